"""A sequence's pose trajectory as a function of time: interpolation between its frames.

:class:`PoseTimeline` holds the sequence's poses ``T_w_b`` (4, 4) at their frame times and
gives the pose at any time through cubic splines: ``scipy``'s ``RotationSpline`` for the
rotation (C2, through every sample) and a cubic spline per axis for the translation; before
the first or after the last sample the end pieces are extended (at most
``max_extrapolation_s``, then held). The pose-camera calibration (:mod:`.calibration`)
evaluates it at shifted times ``t + dt``.

Why not slerp and linear interpolation between neighbours: with fast hand-held rotation the
chord between two frames misses the path. SIMULATED, 25 Hz frames, rotation up to 160
deg/s, a 15 ms offset and a 3 cm lever arm (tests/vio_depth/poses/test_calibration.py's
scene): with slerp/linear the estimated lever arm was off by 23 mm (time offset fine), with
the splines by under 2 mm, as with poses sampled at 1 kHz. At the samples themselves both
give the sample (no offset: no change).
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.spatial.transform import Rotation, RotationSpline

from vio_core.checks import check_array
from vio_core.errors import InputError


class PoseTimeline:
    """Poses ``T_w_b`` at strictly increasing times, interpolated in between (cubic splines).

    Args:
        timestamps: (N,) seconds, strictly increasing, N >= 2.
        poses: (N, 4, 4) body-to-world poses at ``timestamps``, metres.
        max_extrapolation_s: how far beyond the first / last sample the end segment is
            extended (seconds); beyond that the pose is held.

    Raises:
        InputError: fewer than two poses, or timestamps that do not increase.
    """

    def __init__(self, timestamps, poses, max_extrapolation_s: float = 0.2):
        self.timestamps = check_array("timestamps", timestamps, (None,), finite=True).astype(np.float64)
        self.poses = check_array("poses", poses, (len(self.timestamps), 4, 4), finite=True).astype(np.float64)
        if len(self.timestamps) < 2:
            raise InputError(f"a pose timeline needs at least 2 poses, got {len(self.timestamps)}")
        if np.any(np.diff(self.timestamps) <= 0):
            i = int(np.flatnonzero(np.diff(self.timestamps) <= 0)[0])
            raise InputError(f"pose timestamps must increase: sample {i + 1} ({self.timestamps[i + 1]:.6f} s) "
                             f"follows {self.timestamps[i]:.6f} s")
        self.max_extrapolation_s = float(max_extrapolation_s)
        self._rotation = RotationSpline(self.timestamps, Rotation.from_matrix(self.poses[:, :3, :3]))
        self._translation = CubicSpline(self.timestamps, self.poses[:, :3, 3], axis=0)

    def __len__(self) -> int:
        return len(self.timestamps)

    @property
    def span(self) -> tuple[float, float]:
        """(first, last) sample time, seconds."""
        return float(self.timestamps[0]), float(self.timestamps[-1])

    def at(self, t) -> np.ndarray:
        """(K, 4, 4) poses at ``t: (K,)`` seconds (a scalar gives (4, 4))."""
        scalar = np.ndim(t) == 0
        t = check_array("t", np.atleast_1d(np.asarray(t, dtype=np.float64)), (None,), finite=True)
        ts = self.timestamps
        t = np.clip(t, ts[0] - self.max_extrapolation_s, ts[-1] + self.max_extrapolation_s)
        out = np.tile(np.eye(4), (len(t), 1, 1))
        out[:, :3, :3] = self._rotation(t).as_matrix()
        out[:, :3, 3] = self._translation(t)
        return out[0] if scalar else out
