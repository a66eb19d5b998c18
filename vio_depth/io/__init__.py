"""Reading sequences: the :class:`Sequence` contract, the format registry and every loader.

==================  ============================================================================
module              job
==================  ============================================================================
``base``            :class:`Sequence`, :func:`register_format`, :func:`open_sequence`
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
==================  ============================================================================

Importing this package registers every built-in format.
"""

from . import asl, ddad, kitti, kitti_split, native, sevenscenes, tum  # noqa: F401  (importing registers the formats)
from .asl import AslSequence
from .asl_writer import AslWriter
from .base import Sequence, SequenceFormat, available_formats, open_sequence, register_format
from .native import NativeSequence
from .native_writer import NativeSequenceWriter, write_native_sequence

__all__ = [
    "AslSequence",
    "AslWriter",
    "NativeSequence",
    "NativeSequenceWriter",
    "Sequence",
    "SequenceFormat",
    "available_formats",
    "open_sequence",
    "register_format",
    "write_native_sequence",
]
