"""A live view of the pipeline in Rerun (``--rerun``, ``--rerun-save run.rrd``, or from your own loop).

Per frame, on the timelines ``frame`` (index) and ``time`` (the frame's timestamp):

=========================  ==============================================================================
entity                     content
=========================  ==============================================================================
``world/camera``           the camera pose (``Transform3D``, when known) and intrinsics (``Pinhole``)
``world/camera/image``     the camera image
``world/camera/depth``     the metric depth (``DepthImage``, metres)
``world/camera/error``     signed relative error against ground-truth depth (blue near, red far), with GT
``world/camera/points``    the frame's metric points in the camera frame, coloured by their relative
                           error against ground truth when there is some, else by their relative sigma
``world/trajectory``       the camera centres so far (a line, thinned to 1000 points on long runs)
``scale/alpha``, ``/beta`` the fit of ``1/D = alpha d + beta``
``status``                 the frame's status and reason (text log)
``status/points``          metric points fed to the fit
=========================  ==============================================================================

A blueprint lays out the 3D scene, the image with its points, the depth and the error
maps, the scale plot and the status log, so the viewer opens ready to read. ``rerun-sdk``
is an optional dependency (``pip install -e '.[viz]'``), imported when a view is made::

    view = RerunView(spawn=True)                      # or save="run.rrd", connect="rerun+http://..."
    for t, image, disparity, T_w_c in source:
        result = stream.push(image, disparity, timestamp=t, T_w_c=T_w_c)
        view.log(result, image, stream.camera, T_w_c=T_w_c)
    view.close()
"""

from __future__ import annotations

import contextlib
import logging
import os
import shutil
import sys
from pathlib import Path

import numpy as np

from vio_core.camera import Camera
from vio_core.errors import InputError, MissingDependencyError

from ..evaluation import CameraTrajectory
from ..export.colormap import colormap_lut
from ..export.preview import error_preview
from ..pipeline import FrameResult

log = logging.getLogger(__name__)

#: |relative error| or relative sigma mapped onto the whole colour scale of the points
POINT_COLOUR_RANGE = 0.2
#: most camera centres in the logged trajectory line (longer runs are thinned evenly)
MAX_TRAJECTORY_POINTS = 1000


def _rerun():
    """The ``rerun`` module, or a MissingDependencyError with the install hint."""
    try:
        import rerun
        import rerun.blueprint
    except ImportError:
        raise MissingDependencyError("rerun-sdk", "viz", "the Rerun view (--rerun, --rerun-save)") from None
    return rerun


def viewer_executable() -> str | None:
    """The Rerun viewer ``--rerun`` spawns: ``rerun`` on PATH, or the one ``rerun-sdk``
    installed beside this Python (a virtual environment that is not activated); None if neither."""
    found = shutil.which("rerun")
    if found:
        return found
    beside = Path(sys.executable).parent / "rerun"
    return str(beside) if beside.is_file() and os.access(beside, os.X_OK) else None


@contextlib.contextmanager
def _viewer_on_path():
    """PATH with the viewer's folder first while Rerun looks the viewer up by name."""
    exe = viewer_executable()
    before = os.environ.get("PATH", "")
    if exe is not None:
        os.environ["PATH"] = os.pathsep.join([str(Path(exe).parent), before])
    try:
        yield
    finally:
        os.environ["PATH"] = before


def blueprint(rr):
    """The layout: 3D scene | image, depth, error | scale plot and status log."""
    rrb = rr.blueprint
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(name="scene", origin="world"),
            rrb.Vertical(
                rrb.Spatial2DView(name="image + points", origin="world/camera",
                                  contents=["world/camera/image", "world/camera/points"]),
                rrb.Spatial2DView(name="metric depth", origin="world/camera", contents=["world/camera/depth"]),
                rrb.Spatial2DView(name="error vs ground truth", origin="world/camera",
                                  contents=["world/camera/error"]),
            ),
            rrb.Vertical(
                rrb.TimeSeriesView(name="scale (1/D = alpha d + beta)", origin="scale"),
                rrb.TimeSeriesView(name="points", contents=["status/points"]),
                rrb.TextLogView(name="status", origin="status"),
            ),
            column_shares=[2, 2, 1],
        ),
        collapse_panels=True,
    )


class RerunView:
    """Logs pipeline results to a Rerun recording: a viewer it spawns or connects to, and/or an ``.rrd`` file.

    Args:
        spawn: start a viewer (or use the one already listening on the default port).
        connect: URL of a running viewer (``rerun+http://host:9876/proxy``).
        save: write the recording to this ``.rrd`` file (complete when :meth:`close` returns).
        application_id: the recording's application id.
    """

    def __init__(self, *, spawn: bool = False, connect: str | None = None, save=None,
                 application_id: str = "vio-depth"):
        if not (spawn or connect or save):
            raise InputError("a Rerun view needs a viewer (spawn / connect) or a file to save to")
        rr = _rerun()
        self.rr = rr
        self.save_path = None if save is None else Path(save)
        self.rec = rr.RecordingStream(application_id)
        try:
            if self.save_path is not None:
                self.rec.save(str(self.save_path))
            if connect:
                self.rec.connect_grpc(connect)
            elif spawn:
                with _viewer_on_path():
                    self.rec.spawn()
        except Exception as exc:  # no viewer binary, a port in use, an unwritable file
            raise InputError(f"Rerun: {' '.join(str(exc).split())}") from None
        self.rec.send_blueprint(blueprint(rr))
        self._camera: Camera | None = None
        self._centres: list[np.ndarray] = []
        self.frames_logged = 0

    def _set_time(self, index: int, timestamp: float) -> None:
        self.rec.set_time("frame", sequence=int(index))
        if timestamp > 1e8:  # a wall clock (seconds since 1970)
            self.rec.set_time("time", timestamp=float(timestamp))
        else:
            self.rec.set_time("time", duration=float(timestamp))

    def log(self, result: FrameResult, image, camera: Camera, *, T_w_c=None, gt_depth=None) -> None:
        """Log one frame: ``image`` (H, W, 3) uint8 RGB, its ``camera``, the pose ``T_w_c`` (4, 4)
        camera-to-world (or None) and ground-truth depth ``gt_depth`` (H, W) metres (or None)."""
        rr, rec = self.rr, self.rec
        self._set_time(result.frame, result.timestamp)
        if camera != self._camera:
            rec.log("world/camera", rr.Pinhole(image_from_camera=camera.K, width=camera.width, height=camera.height,
                                               camera_xyz=rr.ViewCoordinates.RDF), static=True)
            self._camera = camera
        if T_w_c is not None:
            T = np.asarray(T_w_c, dtype=np.float64)
            rec.log("world/camera", rr.Transform3D(translation=T[:3, 3], mat3x3=T[:3, :3]))
            self._centres.append(T[:3, 3].copy())
            path = np.asarray(self._centres)
            if len(path) > MAX_TRAJECTORY_POINTS:
                path = path[np.unique(np.linspace(0, len(path) - 1, MAX_TRAJECTORY_POINTS).round().astype(int))]
            rec.log("world/trajectory", rr.LineStrips3D([path], colors=[[255, 200, 0]]))
        rec.log("world/camera/image", rr.Image(np.asarray(image)))
        if result.depth is not None:
            rec.log("world/camera/depth", rr.DepthImage(np.asarray(result.depth, np.float32), meter=1.0,
                                                        colormap="turbo"))
            if gt_depth is not None:
                rec.log("world/camera/error", rr.Image(error_preview(result.depth, gt_depth)))
        self._log_points(result, camera, gt_depth)
        fit = result.fit
        if fit is not None and result.depth is not None:
            rec.log("scale/alpha", rr.Scalars([float(fit.alpha)]))
            rec.log("scale/beta", rr.Scalars([float(fit.beta)]))
        rec.log("status/points", rr.Scalars([float(result.points_sampled)]))
        level = "INFO" if result.depth is not None else "WARN"
        rec.log("status", rr.TextLog(f"frame {result.frame} ({result.stem}): {result.status.value}: {result.reason}",
                                     level=level))
        self.frames_logged += 1

    def _log_points(self, result: FrameResult, camera: Camera, gt_depth) -> None:
        uv = result.points_uv
        if uv is None or not len(uv):
            self.rec.log("world/camera/points", self.rr.Clear(recursive=False))
            return
        z = np.asarray(result.points_depth, dtype=np.float64)
        p = camera.backproject(camera.undistort_points(uv), z)
        value = np.full(len(z), np.nan)
        if gt_depth is not None:
            u = np.clip(np.rint(uv[:, 0]).astype(int), 0, camera.width - 1)
            v = np.clip(np.rint(uv[:, 1]).astype(int), 0, camera.height - 1)
            gt = np.asarray(gt_depth, dtype=np.float64)[v, u]
            ok = gt > 0
            value[ok] = (z[ok] - gt[ok]) / gt[ok]
            lut = colormap_lut("coolwarm")
            index = np.clip((value / POINT_COLOUR_RANGE + 1) * 127.5, 0, 255)
        else:
            if result.points_sigma is not None:
                value = np.asarray(result.points_sigma, dtype=np.float64) / np.maximum(z, 1e-9)
            lut = colormap_lut("turbo")
            index = np.clip(value / POINT_COLOUR_RANGE * 255, 0, 255)
        colours = lut[np.nan_to_num(index, nan=0).astype(np.uint8)]
        colours[~np.isfinite(value)] = (200, 200, 200)
        self.rec.log("world/camera/points", self.rr.Points3D(p, colors=colours, radii=self.rr.Radius.ui_points(3.0)))

    def log_trajectory(self, trajectory: CameraTrajectory) -> None:
        """The run's final camera trajectory as one line (static)."""
        if len(trajectory) >= 2:
            self.rec.log("world/trajectory_final", self.rr.LineStrips3D([trajectory.positions]), static=True)

    def close(self) -> None:
        """Flush and disconnect: an ``.rrd`` file is complete afterwards."""
        self.rec.flush()
        self.rec.disconnect()


def frame_pose(frame, result: FrameResult):
    """The camera-to-world pose the run has for ``frame`` now: the landmark window's, the
    odometry's (``--poses vio``), else ``frame.T_w_c`` -- in a run the run's own pose of the
    frame (:mod:`vio_depth.run.output_poses`: the sequence's only under ``--poses gt``);
    None when none is known."""
    if result.points.T_w_c is not None:
        return result.points.T_w_c
    if result.frame_pose is not None and result.frame_pose.ok and result.frame_pose.T_w_c is not None:
        return result.frame_pose.T_w_c
    return frame.T_w_c


class RerunSink:
    """A :class:`~vio_depth.run.sinks.FrameSink` logging every frame of a run to a :class:`RerunView`.

    With ``save``, the recording is written to ``<save>.partial`` and renamed to ``save`` when
    the run succeeds (an interrupted run leaves no half-written ``.rrd`` under the name).
    """

    def __init__(self, *, spawn: bool = False, connect: str | None = None, save=None):
        self.final = None if save is None else Path(save)
        partial = None if save is None else self.final.with_name(self.final.name + ".partial")
        self.view = RerunView(spawn=spawn, connect=connect, save=partial)

    def add_frame(self, frame, result: FrameResult) -> None:
        self.view.log(result, frame.image(), frame.camera, T_w_c=frame_pose(frame, result),
                      gt_depth=frame.gt_depth())

    def finish(self, sequence, trajectory: CameraTrajectory | None) -> Path | None:
        if trajectory is not None:
            self.view.log_trajectory(trajectory)
        self.view.close()
        if self.final is not None:
            os.replace(self.view.save_path, self.final)
        return self.final

    def abort(self) -> None:
        """Close the view; a partial ``.rrd`` is removed (a resumed run logs every frame again)."""
        try:
            self.view.close()
        except Exception:  # the run's own error is what the user needs to see
            log.debug("closing the Rerun view after a failed run", exc_info=True)
        if self.view.save_path is not None:
            self.view.save_path.unlink(missing_ok=True)


__all__ = ["MAX_TRAJECTORY_POINTS", "POINT_COLOUR_RANGE", "RerunSink", "RerunView", "blueprint", "frame_pose",
           "viewer_executable"]
