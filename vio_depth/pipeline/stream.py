"""Pushing frames from arrays: the pipeline for a ROS node, a notebook or any live source.

:class:`FrameStream` takes, per frame, the image, its disparity, the timestamp and a pose
(``T_w_c``) and/or the IMU samples since the previous frame, and returns the frame's
:class:`~vio_depth.pipeline.FrameResult`. No sequence folder and no adapter classes::

    stream = FrameStream(camera, PipelineSettings.from_presets(pairing="indoor"))
    for t, image, disparity, T_w_c in source:
        result = stream.push(image, disparity, timestamp=t, T_w_c=T_w_c)
        if result.depth is not None:
            ...  # (H, W) float32 metres, NaN = invalid
"""

from __future__ import annotations

import numpy as np

from vio_core.camera import Camera
from vio_core.checks import check_array, check_image, check_transform
from vio_core.errors import InputError

from ..disparity import DisparityKind, check_disparity
from ..frame import Frame, ImuData
from .build import build_matcher, build_pose_stage
from .feed import StreamInputs
from .pipeline import Pipeline
from .result import FrameResult
from .settings import PipelineSettings


class _GivenDisparity:
    """The disparity handed over with the frame being pushed."""

    kind = DisparityKind.ARRAY

    def __init__(self):
        self.current: np.ndarray | None = None

    def __call__(self, frame: Frame) -> np.ndarray | None:
        if self.current is None:
            return None
        return check_disparity(self.current, frame, f"disparity of frame {frame.index}")


class FrameStream:
    """The streaming pipeline fed with arrays, one frame at a time.

    Args:
        camera: intrinsics of the images.
        settings: pipeline settings; ``settings.poses`` decides what each push needs: the
            ``gt`` source takes ``T_w_c`` (camera-to-world, metres), the ``imu`` source the
            IMU samples (and ``imu_calibration``), plus ``T_w_c`` when known; the ``vio``
            source the IMU samples and ``imu_calibration`` only (a ``T_w_c`` is ignored).
        imu_calibration: for the ``imu`` and ``vio`` pose sources: an
            :class:`~vio_depth.frame.ImuData` whose ``T_c_i``, noise densities and gravity
            are used (its samples are ignored).
        pose_kind: what the pushed ``T_w_c`` are (a
            :data:`~vio_depth.poses.POSE_UNCERTAINTY_PRESETS` name: ``mocap``, ``ins``,
            ``headset``, ``kinectfusion``; ``exact`` for rendered poses), for the ``gt``
            source's stated uncertainty when ``settings.poses.uncertainty`` names none.
    """

    def __init__(self, camera: Camera, settings: PipelineSettings | None = None, *,
                 imu_calibration: ImuData | None = None, pose_kind: str = "exact"):
        settings = PipelineSettings() if settings is None else settings
        if not isinstance(camera, Camera):
            raise InputError(f"camera must be a vio_core.Camera, got {type(camera).__name__}")
        self.camera = camera
        self._disparity = _GivenDisparity()
        self._inputs = StreamInputs(pose_kind, imu_calibration)
        matcher = build_matcher(settings)
        poses = build_pose_stage(settings.poses, matcher=matcher, stream=self._inputs)
        self.pipeline = Pipeline(settings, poses, self._disparity, matcher=matcher, imu_of=lambda: self._inputs.imu)

    @property
    def settings(self) -> PipelineSettings:
        return self.pipeline.settings

    def push(self, image, disparity, *, timestamp: float | None = None, T_w_c=None, imu=None,
             gt_depth=None) -> FrameResult:
        """Process the next frame.

        Args:
            image: (H, W, 3) uint8 RGB (or (H, W) grey) of the camera's size.
            disparity: (H, W) float affine-invariant disparity (bigger = nearer), NaN = invalid,
                or None (the frame then gets status no_disparity).
            timestamp: seconds, increasing (default: the frame number).
            T_w_c: (4, 4) camera-to-world pose, metres, or None.
            imu: the IMU samples since the previous push: ``(t (M,) s, gyro (M, 3) rad/s,
                accel (M, 3) m/s^2)``, or None.
            gt_depth: (H, W) metres ground truth (0 = invalid), for reference point sources.

        Raises:
            ShapeError / InputError: wrongly shaped arrays, decreasing time, a missing input
                the pose source needs.
        """
        index = len(self._inputs)
        image = np.asarray(image)
        if image.ndim == 2:
            image = np.repeat(image[:, :, None], 3, axis=2)
        image = check_image("image", image, channels=3)
        if image.shape[:2] != (self.camera.height, self.camera.width) or image.dtype != np.uint8:
            raise InputError(f"image: expected ({self.camera.height}, {self.camera.width}, 3) uint8, "
                             f"got {image.shape} {image.dtype}")
        t = float(index if timestamp is None else timestamp)
        frames = self._inputs.frames
        if frames and not t > frames[-1].timestamp:
            raise InputError(f"timestamps must increase: {t} after {frames[-1].timestamp}")
        pose = None if T_w_c is None else check_transform("T_w_c", T_w_c)
        depth = None if gt_depth is None else check_array("gt_depth", gt_depth, image.shape[:2]).astype(np.float32)
        if imu is not None:
            self._inputs.add_imu(*imu)
        frame = Frame(index, t, f"{index:06d}", self.camera, pose, load_image=lambda: image,
                      load_gt_depth=None if depth is None else (lambda: depth))
        self._inputs.add_frame(frame)
        self._disparity.current = None if disparity is None else np.asarray(disparity)
        try:
            return self.pipeline.process(frame)
        finally:
            self._disparity.current = None
