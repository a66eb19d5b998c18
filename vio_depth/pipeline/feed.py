"""What a :class:`~vio_depth.pipeline.FrameStream` gives its pose source in place of a sequence.

:class:`StreamInputs` holds the frames pushed so far (the ``imu`` source reads their poses as
it reads a sequence's), the kind of the pushed poses, the IMU calibration and the IMU samples
pushed so far. :class:`LazyImuPoses` is the ``imu`` or ``vio`` pose source of a stream:
:func:`~vio_depth.pipeline.build_pose_stage` gives it the function that builds the source
from IMU samples; it builds the source when it is first asked for a pose after samples
arrived, and hands it the grown samples after.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Callable

import numpy as np

from matchers import Features, Matcher
from vio_core.checks import check_array
from vio_core.errors import InputError

from ..frame import Frame, ImuData
from ..poses import FramePose, RelativePose
from ..vio import VioPoseSource

#: the reason of every pose asked for before the first IMU samples
NO_SAMPLES_YET = "no IMU samples pushed yet"


def _image_not_kept() -> np.ndarray:
    raise InputError("a stream keeps the timestamps and poses of past frames, not their images")


class StreamInputs:
    """The frames and IMU samples pushed to a stream (what a sequence gives a pose source).

    A long stream keeps only what its pose source reads again: :meth:`forget_before` drops
    the frames and the samples before a time (the stream asks its source how far back it
    reads: :meth:`LazyImuPoses.samples_needed_since`). Without that, a stream at 20 Hz with
    a 200 Hz IMU grew by about 1.5 KiB a frame, and re-joined every sample at each push.

    Args:
        pose_kind: what the pushed ``T_w_c`` are (a
            :data:`~vio_depth.poses.POSE_UNCERTAINTY_PRESETS` name), for the ``gt`` source.
        imu_calibration: an :class:`~vio_depth.frame.ImuData` whose ``T_c_i``, noise densities
            and gravity the pushed samples get (its own samples are ignored), or None (the
            pushed samples are then not kept: nothing could read them).
    """

    #: samples kept before the time given to :meth:`forget_before` (a window's interpolation and
    #: ``ImuFactors.samples_between`` read up to two beyond an interval's ends)
    SAMPLES_BEFORE = 4

    def __init__(self, pose_kind: str = "exact", imu_calibration: ImuData | None = None):
        self.pose_kind = pose_kind
        self.imu_calibration = imu_calibration
        #: the frames kept, in order, without their pixels (:meth:`add_frame`); the first is
        #: pushed frame number ``first``
        self.frames: list[Frame] = []
        self.first = 0
        #: the samples kept with the calibration; None before the first ones or without calibration
        self.imu: ImuData | None = None

    def __len__(self) -> int:
        """Frames pushed so far (kept or forgotten)."""
        return self.first + len(self.frames)

    def __getitem__(self, index: int) -> Frame:
        """Pushed frame number ``index``. Raises IndexError for a forgotten or future one."""
        if not 0 <= index - self.first < len(self.frames):
            raise IndexError(f"stream frame {index} is not kept (frames {self.first}-{len(self) - 1} are)")
        return self.frames[index - self.first]

    def add_frame(self, frame: Frame) -> None:
        """Append ``frame``, keeping its index, timestamp and pose only: a pose source reads
        nothing else of past frames, and keeping every pushed image (and depth) would grow
        a long stream's memory by a frame's pixels per push."""
        self.frames.append(replace(frame, load_image=_image_not_kept, load_gt_depth=None))

    def add_imu(self, t, gyro, accel) -> None:
        """Append IMU samples: ``t`` (M,) seconds, ``gyro`` (M, 3) rad/s, ``accel`` (M, 3) m/s^2.

        Raises:
            ShapeError: wrongly shaped or non-finite arrays.
        """
        t = check_array("imu t", t, (None,), finite=True)
        gyro = check_array("imu gyro", gyro, (len(t), 3), finite=True)
        accel = check_array("imu accel", accel, (len(t), 3), finite=True)
        cal = self.imu_calibration
        if len(t) == 0 or cal is None:
            return
        old = self.imu
        if old is not None:
            t, gyro, accel = (np.concatenate([old.t, t]), np.concatenate([old.gyro, gyro]),
                              np.concatenate([old.accel, accel]))
        self.imu = ImuData(t, gyro, accel, cal.T_c_i, cal.gyro_noise, cal.accel_noise, cal.gyro_bias_walk,
                           cal.accel_bias_walk, cal.gravity_w)

    def forget_before(self, t: float) -> None:
        """Drop the frames before ``t`` seconds and the samples before it but the last
        :attr:`SAMPLES_BEFORE` (what the pose source will not read again)."""
        drop = 0
        while drop < len(self.frames) and self.frames[drop].timestamp < t:
            drop += 1
        if drop:
            del self.frames[:drop]
            self.first += drop
        imu = self.imu
        if imu is not None:
            i0 = int(np.searchsorted(imu.t, t, "left")) - self.SAMPLES_BEFORE
            if i0 > 0:  # copies: a view would keep the whole array alive
                self.imu = replace(imu, t=imu.t[i0:].copy(), gyro=imu.gyro[i0:].copy(), accel=imu.accel[i0:].copy())


class LazyImuPoses:
    """A stream's ``imu`` or ``vio`` pose source, built from its IMU samples when they arrive.

    Args:
        name: the source's ``--poses`` name.
        inputs: the stream's inputs; their ``imu`` is read at every call.
        build: builds the source from the samples so far (an :class:`~vio_depth.poses.ImuPoseSource`
            or a :class:`~vio_depth.vio.VioPoseSource`); the source is then handed the grown
            samples with its ``update_samples``.
        matcher: the matcher of a source that tracks the frames (``vio``), else None.

    :meth:`track` and :meth:`world_pose` are the tracking source's
    (:class:`~vio_depth.poses.TrackingPoseSource`); whether a stream's source tracks is said by
    the :class:`~vio_depth.pipeline.PoseStage` it comes in, not by these methods.
    """

    def __init__(self, name: str, inputs: StreamInputs, build: Callable[[ImuData], object],
                 matcher: Matcher | None = None):
        self.name = name
        self.matcher = matcher
        self._inputs = inputs
        self._build = build
        self._seen: ImuData | None = None
        #: the source, once the first samples arrived
        self.source = None

    def _current(self):
        imu = self._inputs.imu
        if imu is not None and imu is not self._seen:
            if self.source is None:
                self.source = self._build(imu)
            else:
                self.source.update_samples(imu)
            self._seen = imu
        return self.source

    def samples_needed_since(self) -> float | None:
        """Seconds before which the source reads no frame or IMU sample of the stream again,
        or None when it may read any (the ``imu`` source: its static start reads the first
        samples; its bias fit, past frames' poses)."""
        return self.source.samples_needed_since() if isinstance(self.source, VioPoseSource) else None

    def relative(self, keyframe: Frame, current: Frame) -> RelativePose:
        source = self._current()
        if source is None:
            return RelativePose(None, ok=False, reason=NO_SAMPLES_YET)
        return source.relative(keyframe, current)

    def track(self, frame: Frame, features: Features) -> FramePose:
        source = self._current()
        if source is None:
            return FramePose(None, ok=False, status="initialising", reason=NO_SAMPLES_YET)
        return source.track(frame, features)

    def world_pose(self, frame: Frame) -> np.ndarray | None:
        source = self._current()
        return None if source is None else source.world_pose(frame)

    def finish(self) -> None:
        """The odometry's :meth:`~vio_depth.vio.VioPoseSource.finish` (nothing to settle otherwise)."""
        if isinstance(self.source, VioPoseSource):
            self.source.finish()

    def frame_landmarks(self, frame: Frame):
        """The landmarks the odometry saw in ``frame``
        (:meth:`~vio_depth.vio.VioPoseSource.frame_landmarks`; ``vio`` only), or None before
        the first samples."""
        source = self._current()
        return None if source is None else source.frame_landmarks(frame)
