"""Looking at the pipeline while it runs: a live view in Rerun (``--rerun``, ``--rerun-save``).

=================  ============================================================================
module             job
=================  ============================================================================
``rerun_view``     :class:`RerunView` (log :class:`~vio_depth.pipeline.FrameResult` s from any
                   loop, e.g. :class:`~vio_depth.pipeline.FrameStream`), :class:`RerunSink` (a
                   run's frame sink), the blueprint
=================  ============================================================================

``rerun-sdk`` is optional (``pip install -e '.[viz]'``): it is imported when a view is made.
Foxglove and RViz read the run's MCAP / ROS 2 output instead (:mod:`vio_depth.export.rosout`).
"""

from .rerun_view import POINT_COLOUR_RANGE, RerunSink, RerunView, blueprint, frame_pose, viewer_executable

__all__ = ["POINT_COLOUR_RANGE", "RerunSink", "RerunView", "blueprint", "frame_pose", "viewer_executable"]
