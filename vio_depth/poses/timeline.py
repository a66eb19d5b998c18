"""A sequence's pose trajectory as a function of time: interpolation between its frames.

:class:`PoseTimeline` holds the sequence's poses ``T_w_b`` (4, 4) at their frame times and
gives the pose at any time by local cubic (Lagrange) interpolation through the four samples
around it: the rotation in the tangent space of the segment's first sample
(``R(t) = R_j Exp(sum_k w_k(t) Log(R_j^T R_k))``), the translation per axis. At the ends the
four samples are the first or last four (one-sided, no boundary condition to assume); before
the first or after the last sample the end cubic is extended (at most
``max_extrapolation_s``, then held). Fewer than four samples give a lower order (two:
linear). The pose-camera calibration (:mod:`.calibration`) evaluates it at shifted times
``t + dt``.

Why cubic: with fast hand-held rotation the chord between two frames misses the path.
SIMULATED, 25 Hz frames, rotation up to 160 deg/s, a 15 ms offset and a 3 cm lever arm
(tests/vio_depth/poses/calibration_scene.py): with slerp / linear interpolation the
estimated lever arm was off by 23 mm (the time offset was fine), with cubic interpolation by
under 2 mm, as with poses sampled at 1 kHz. Why local and not a global spline: scipy's
``RotationSpline`` (natural end conditions) missed the true rotation by 0.06 deg in the
first interval and by 0.26 deg 15 ms beyond the last sample on the room benchmark's
trajectory (30 Hz, ~100 deg/s; ``benchmarks/bench_pose_calibration.py``), enough to double
those frames' depth error at centimetre baselines; the local cubic: 0.001 and 0.007 deg.
At the samples themselves every scheme gives the sample (no offset: no change).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from vio_core.checks import check_array
from vio_core.errors import InputError
from vio_core.geometry import so3_exp, so3_log

#: samples per interpolation stencil (4: cubic)
_STENCIL = 4


class PoseTimeline:
    """Poses ``T_w_b`` at strictly increasing times, interpolated in between (local cubic).

    Args:
        timestamps: (N,) seconds, strictly increasing, N >= 2.
        poses: (N, 4, 4) body-to-world poses at ``timestamps``, metres.
        max_extrapolation_s: how far beyond the first / last sample the end cubic is
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
        # the nearest rotation of each sample (poses read from files are orthonormal to ~1e-6 only)
        self._rotations = Rotation.from_matrix(self.poses[:, :3, :3]).as_matrix()

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
        ts, n = self.timestamps, len(self.timestamps)
        t = np.clip(t, ts[0] - self.max_extrapolation_s, ts[-1] + self.max_extrapolation_s)
        m = min(_STENCIL, n)
        j = np.clip(np.searchsorted(ts, t, side="right") - 1, 0, n - 2)  # segment [j, j + 1]
        lo = np.clip(j - (m - 1) // 2, 0, n - m)
        idx = lo[:, None] + np.arange(m)  # (K, m) the stencil's samples
        tk = ts[idx]
        # Lagrange weights w_k(t) = prod_{l != k} (t - t_l) / (t_k - t_l)
        diff = t[:, None, None] - tk[:, None, :]  # (K, 1, m): t - t_l
        den = tk[:, :, None] - tk[:, None, :]  # (K, m, m): t_k - t_l
        eye = np.eye(m, dtype=bool)
        w = np.prod(np.where(eye, 1.0, np.broadcast_to(diff, den.shape) / np.where(eye, 1.0, den)), axis=2)
        R = self._rotations
        R_j = R[j]
        phi = so3_log(np.swapaxes(R_j, -1, -2)[:, None] @ R[idx])  # (K, m, 3): Log(R_j^T R_k)
        out = np.tile(np.eye(4), (len(t), 1, 1))
        out[:, :3, :3] = R_j @ so3_exp(np.einsum("km,kmd->kd", w, phi))
        out[:, :3, 3] = np.einsum("km,kmd->kd", w, self.poses[idx, :3, 3])
        return out[0] if scalar else out
