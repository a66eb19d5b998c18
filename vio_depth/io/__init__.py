"""Reading sequences: the :class:`Sequence` contract, the table of formats and every loader.

==================  ============================================================================
module              job
==================  ============================================================================
``base``            :class:`Sequence`, :class:`SequenceFormat`
``formats``         :data:`FORMATS` (every loader's ``FORMAT``, in detection order), :func:`open_sequence`
``tables``          the one line-based text-table reader (``file:line`` errors), TUM trajectories
``images``          reading images (bytes by Python, decoding by OpenCV)
``decode``          decoding with the codec's warnings as errors (corrupt JPEG, damaged PNG)
``depth_png``       16-bit depth PNGs (KITTI convention), atomic file writes
``rasterize``       depth images from points, depth re-projection between cameras
``native``          the native format (reader); ``native_writer`` writes it
``kitti``           KITTI raw drives; ``kitti_oxts`` their calibration and OXTS pose recipe
``kitti_split``     KITTI split files (the Eigen test split) mapped to drives and frame indices
``ddad``            DDAD scenes in the published DGP layout
``sevenscenes``     Microsoft 7-Scenes
``tum``             TUM RGB-D
``asl``             EuRoC / TUM-VI (ASL layout, ``mav0/``); ``asl_writer`` writes it
``bag``             ROS 1 / ROS 2 bags and MCAP files (``rosbags``); ``bag_topics`` the topic choice
                    and ``inspect``, ``bag_messages`` the message conversions
``kalibr``          Kalibr ``camchain.yaml`` / ``imu.yaml`` (``--calib``, ``--imu-calib``) for any input
==================  ============================================================================
"""

from .asl import AslSequence
from .asl_writer import AslWriter
from .bag import BagSequence, BagSettings, open_bag
from .base import Sequence, SequenceFormat
from .formats import FORMATS, available_formats, open_sequence
from .kalibr import Calibration, apply_calibration, read_calibration
from .native import NativeSequence
from .native_writer import NativeSequenceWriter, write_native_sequence

__all__ = [
    "FORMATS",
    "AslSequence",
    "AslWriter",
    "BagSequence",
    "BagSettings",
    "Calibration",
    "NativeSequence",
    "NativeSequenceWriter",
    "Sequence",
    "SequenceFormat",
    "apply_calibration",
    "available_formats",
    "open_bag",
    "open_sequence",
    "read_calibration",
    "write_native_sequence",
]
