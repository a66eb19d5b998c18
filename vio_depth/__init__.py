"""vio-depth: metric depth maps for a monocular camera robot, without a LiDAR.

A depth foundation model predicts an affine-invariant disparity ``d`` per image; metric depth
is ``1/D = alpha*d + beta`` with ``(alpha, beta)`` fitted per image against sparse metric
points triangulated with metric (ground-truth or IMU) poses.

The public API::

    from vio_depth import Pipeline, PipelineSettings, open_sequence, run_sequence

    sequence = open_sequence("sample_sequences/street")
    pipeline = Pipeline(PipelineSettings(), sequence=sequence)
    summary = run_sequence(sequence, pipeline, "out/street")

or, frame by frame from arrays (a ROS node, a notebook), :class:`FrameStream`.

The data flow, one subpackage per stage: :mod:`~vio_depth.io` (sequences, frames) ->
:mod:`~vio_depth.disparity` -> :mod:`matchers` (features, matches) -> :mod:`~vio_depth.poses`
+ :mod:`triangulation` (metric points, in :mod:`~vio_depth.pipeline`) -> :mod:`~vio_depth.rescale`
(fit, depth) -> :mod:`~vio_depth.run` (outputs), with :mod:`~vio_depth.evaluation` against
ground truth. docs/design.md has the table of modules and public names.

The library logs through the standard :mod:`logging` module under the ``vio_depth`` logger
(a NullHandler is installed: nothing is printed unless the application configures logging).
"""

import logging

from vio_core import Camera, InputError, SettingsError, VioDepthError

from ._version import __version__
from .disparity import DisparitySettings, create_disparity_source
from .frame import Frame, ImuData
from .io import Sequence, open_sequence
from .pipeline import FrameResult, FrameStatus, FrameStream, Pipeline, PipelineSettings, create_pose_source
from .run import RunSettings, RunSummary, dump_config, load_config, run_sequence

logging.getLogger(__name__).addHandler(logging.NullHandler())

__all__ = [
    "Camera",
    "DisparitySettings",
    "Frame",
    "FrameResult",
    "FrameStatus",
    "FrameStream",
    "ImuData",
    "InputError",
    "Pipeline",
    "PipelineSettings",
    "RunSettings",
    "RunSummary",
    "Sequence",
    "SettingsError",
    "VioDepthError",
    "__version__",
    "create_disparity_source",
    "create_pose_source",
    "dump_config",
    "load_config",
    "open_sequence",
    "run_sequence",
]
