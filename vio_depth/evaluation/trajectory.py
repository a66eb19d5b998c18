"""Camera trajectories: TUM files, ATE and RPE with evo's definitions (reproduced, not imported).

Definitions (those of evo 1.38, https://github.com/MichaelGrupp/evo, ``evo_ape`` / ``evo_rpe``
with ``--pose_relation trans_part`` and ``angle_deg``; tests/vio_depth/evaluation compares
with evo itself where it is installed -- it is not a dependency):

* **Association** (:func:`associate`, evo ``sync.associate_trajectories``): for every
  stamp of the *shorter* trajectory, the nearest stamp of the longer one, kept when they
  differ by at most ``max_diff`` seconds (default 0.01 s;
  :func:`vio_depth.io.tables.associate_nearest`).
* **Alignment** (:func:`umeyama_alignment`, evo ``geometry.umeyama_alignment``): the
  least-squares ``R, t`` (and with ``with_scale`` a scale ``c``) with
  ``p_ref ~ c R p_est + t`` over the associated positions (Umeyama 1991).
* **ATE** (:func:`absolute_trajectory_error`, ``evo_ape -a``): the estimate is aligned to
  the reference with SE(3) Umeyama -- **no scale correction**: metric scale is what is
  evaluated -- and the error of pose ``i`` is ``|p_ref,i - (R p_est,i + t)|``; ATE is the
  RMSE over the associated poses. The Sim(3) Umeyama scale is reported separately as
  a diagnostic (``scale``: 1.0 = metric scale right; it is *not* applied).
* **RPE** (:func:`relative_pose_error`, ``evo_rpe --delta D --delta_unit m``): pose pairs
  ``(i, j)`` chosen by travelled path length on the *estimate* (evo's default; see
  :func:`pairs_by_path` for evo's exact rule), relative error
  ``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)`` with ``Q`` the reference and ``P`` the estimate
  (camera-to-world); translation error ``|t(E)|`` metres, rotation error
  ``|log(R(E))|`` degrees. No alignment is needed (RPE is invariant to a rigid
  transform of either trajectory).

Statistics follow evo: rmse, mean, median, std (population), min, max.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from vio_core.checks import check_array
from vio_core.errors import InputError, SettingsError

from ..io.depth_png import write_bytes_atomic
from ..io.tables import associate_nearest, format_tum_trajectory, read_tum_trajectory


@dataclass(frozen=True)
class CameraTrajectory:
    """Stamped camera poses.

    Attributes:
        t: (N,) seconds, strictly increasing.
        T_w_c: (N, 4, 4) camera-to-world transforms, metres.
    """

    t: np.ndarray
    T_w_c: np.ndarray

    def __post_init__(self):
        t = check_array("t", self.t, (None,), finite=True)
        check_array("T_w_c", self.T_w_c, (len(t), 4, 4), finite=True)
        if len(t) > 1 and np.any(np.diff(t) <= 0):
            raise InputError("trajectory timestamps must be strictly increasing")

    def __len__(self) -> int:
        return len(self.t)

    @property
    def positions(self) -> np.ndarray:
        """(N, 3) camera centres in the world, metres."""
        return self.T_w_c[:, :3, 3]

    def path_length(self) -> float:
        """Travelled distance, metres (sum of the steps between consecutive positions)."""
        return float(np.linalg.norm(np.diff(self.positions, axis=0), axis=1).sum()) if len(self) > 1 else 0.0

    @classmethod
    def from_optional_poses(cls, t, T_w_c) -> "CameraTrajectory":
        """From ``t: (N,)`` seconds and N poses (each (4, 4) camera-to-world or None): the posed ones."""
        t = check_array("t", t, (None,), finite=True)
        poses = list(T_w_c)
        if len(poses) != len(t):
            raise InputError(f"{len(t)} timestamps but {len(poses)} poses")
        keep = [i for i, T in enumerate(poses) if T is not None]
        T = np.stack([np.asarray(poses[i], float) for i in keep]) if keep else np.zeros((0, 4, 4))
        return cls(t[keep], T)


# --------------------------------------------------------------------------- TUM files
def write_trajectory_tum(path, trajectory: CameraTrajectory) -> Path:
    """Write ``trajectory`` as a TUM file ``t tx ty tz qx qy qz qw`` (camera-to-world, metres,
    timestamps to the nanosecond), one line per pose, atomically (a temporary file renamed
    into place). Returns ``path``."""
    text = format_tum_trajectory(trajectory.t, trajectory.T_w_c, time_decimals=9)
    write_bytes_atomic(Path(path), text.encode())
    return Path(path)


def read_trajectory_tum(path) -> CameraTrajectory:
    """Read a TUM trajectory file (errors name the file and line, see
    :func:`vio_depth.io.tables.read_tum_trajectory`)."""
    t, T = read_tum_trajectory(path)
    return CameraTrajectory(t, T)


# --------------------------------------------------------------------------- association, alignment
def associate(t_est, t_ref, max_diff: float = 0.01) -> tuple[np.ndarray, np.ndarray]:
    """Matching indices of two stamp lists (evo's rule, see the module docstring).

    Args:
        t_est: (N,) seconds. t_ref: (M,) seconds. max_diff: seconds.

    Returns:
        ``(i_est (K,), i_ref (K,))`` int64 index arrays, in order of the shorter list.
    """
    a = check_array("t_est", t_est, (None,), finite=True)
    b = check_array("t_ref", t_ref, (None,), finite=True)
    if len(a) == 0 or len(b) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    est_longer = len(a) > len(b)
    short, long_ = (b, a) if est_longer else (a, b)
    order = np.argsort(long_, kind="stable")
    nearest = associate_nearest(short, long_[order], max_diff)
    i_short = np.flatnonzero(nearest >= 0).astype(np.int64)
    i_long = order[nearest[i_short]].astype(np.int64)
    return (i_long, i_short) if est_longer else (i_short, i_long)


def umeyama_alignment(x, y, with_scale: bool = False) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares ``R (3, 3), t (3,), c`` with ``y ~ c R x + t`` (Umeyama 1991, as evo).

    Args:
        x: (N, 3) source points (the estimate), metres. y: (N, 3) target points (the reference).
        with_scale: also estimate ``c`` (else ``c = 1``).

    Raises:
        InputError: fewer than 3 points, all source points coincide, or positions so large
            that their spread overflows (LAPACK's SVD may never return on inf / NaN: a pose
            with ``tx = 1e300`` hung it, issue 23).
    """
    x = check_array("x", x, (None, 3), finite=True)
    y = check_array("y", y, (len(x), 3), finite=True)
    if len(x) < 3:
        raise InputError(f"alignment needs at least 3 associated poses, got {len(x)}")
    with np.errstate(over="ignore", invalid="ignore"):
        mx, my = x.mean(0), y.mean(0)
        sigma_x = float(np.mean(np.sum((x - mx) ** 2, axis=1)))
        cov = (y - my).T @ (x - mx) / len(x)
    if not (np.isfinite(sigma_x) and np.all(np.isfinite(cov)) and np.all(np.isfinite(my))):
        raise InputError("alignment impossible: the positions are so large that their spread overflows "
                         f"(largest |coordinate| {max(np.abs(x).max(), np.abs(y).max()):.3g} m)")
    if sigma_x <= 0:
        raise InputError("alignment is degenerate: all estimated positions coincide")
    u, d, vt = np.linalg.svd(cov)
    s = np.eye(3)
    if np.linalg.det(u) * np.linalg.det(vt) < 0:
        s[2, 2] = -1.0
    R = u @ s @ vt
    c = float(np.trace(np.diag(d) @ s) / sigma_x) if with_scale else 1.0
    t = my - c * R @ mx
    return R, t, c


# --------------------------------------------------------------------------- statistics
@dataclass(frozen=True)
class ErrorStats:
    """evo's statistics of a list of errors (units of the errors)."""

    rmse: float
    mean: float
    median: float
    std: float
    min: float
    max: float
    n: int

    @classmethod
    def of(cls, errors) -> "ErrorStats":
        e = np.asarray(errors, dtype=np.float64)
        if len(e) == 0:
            nan = float("nan")
            return cls(nan, nan, nan, nan, nan, nan, 0)
        return cls(float(np.sqrt(np.mean(e**2))), float(e.mean()), float(np.median(e)), float(e.std()),
                   float(e.min()), float(e.max()), len(e))

    def to_json(self) -> dict:
        return {k: getattr(self, k) for k in ("rmse", "mean", "median", "std", "min", "max", "n")}


@dataclass(frozen=True)
class AteResult:
    """Absolute trajectory error after SE(3) alignment (no scale correction).

    Attributes:
        translation: statistics of the per-pose position errors, metres (``rmse`` is the ATE).
        errors: (K,) metres, per associated pose.
        i_est, i_ref: (K,) associated indices.
        T_ref_est: (4, 4) the SE(3) alignment applied to the estimate.
        scale: Sim(3) Umeyama scale of the estimate (diagnostic only, not applied; 1 = right scale).
        path_length: metres travelled by the reference over the associated poses.
    """

    translation: ErrorStats
    errors: np.ndarray
    i_est: np.ndarray
    i_ref: np.ndarray
    T_ref_est: np.ndarray
    scale: float
    path_length: float

    @property
    def rmse(self) -> float:
        return self.translation.rmse

    def to_json(self) -> dict:
        return {"ate_m": self.translation.to_json(), "sim3_scale": self.scale, "path_length_m": self.path_length,
                "ate_fraction_of_path": self.rmse / self.path_length if self.path_length > 0 else None}


def absolute_trajectory_error(est: CameraTrajectory, ref: CameraTrajectory, max_diff: float = 0.01) -> AteResult:
    """ATE of ``est`` against ``ref`` (see the module docstring).

    Raises:
        InputError: fewer than 3 associated poses, or a degenerate (point) estimate.
    """
    i_est, i_ref = associate(est.t, ref.t, max_diff)
    p_est, p_ref = est.positions[i_est], ref.positions[i_ref]
    R, t, _ = umeyama_alignment(p_est, p_ref, with_scale=False)
    _, _, scale = umeyama_alignment(p_est, p_ref, with_scale=True)
    errors = np.linalg.norm(p_ref - (p_est @ R.T + t), axis=1)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    path = float(np.linalg.norm(np.diff(p_ref, axis=0), axis=1).sum())
    return AteResult(ErrorStats.of(errors), errors, i_est, i_ref, T, scale, path)


# --------------------------------------------------------------------------- RPE
def pairs_by_path(positions, delta: float, tol: float = 0.0, all_pairs: bool = False) -> list[tuple[int, int]]:
    """Pose pairs ``delta`` metres of travelled path apart (evo ``filters.filter_pairs_by_path``).

    Consecutive mode (default): index 0 is marked, then, walking along the path, every
    index where the path since the last mark reaches ``delta``; consecutive marks form the
    pairs (evo 1.38; evo before about 1.26 did not mark index 0, so its first pair started
    where the path first reached ``delta``). ``all_pairs``: for every ``i``, the later ``j``
    whose path distance from ``i`` is nearest to ``delta``, kept when within ``tol``.

    Args:
        positions: (N, 3) metres.
    """
    p = check_array("positions", positions, (None, 3), finite=True)
    if len(p) < 2:
        return []
    steps = np.linalg.norm(np.diff(p, axis=0), axis=1)
    if all_pairs:
        dist = np.concatenate([[0.0], np.cumsum(steps)])
        pairs = []
        for i in range(len(p) - 1):
            ahead = dist[i + 1:] - dist[i]
            k = int(np.argmin(np.abs(ahead - delta)))
            if abs(ahead[k] - delta) <= tol:
                pairs.append((i, i + 1 + k))
        return pairs
    ids, path = [0], 0.0
    for i in range(1, len(p)):  # sequential by definition: the reset depends on the previous marks
        path += float(steps[i - 1])
        if path >= delta:
            ids.append(i)
            path = 0.0
    return list(zip(ids, ids[1:]))


@dataclass(frozen=True)
class RpeResult:
    """Relative pose error over ``delta`` metres.

    Attributes:
        delta_m: the path distance of the pairs, metres.
        translation: statistics of ``|t(E)|``, metres.
        rotation_deg: statistics of the rotation angle of ``E``, degrees.
        pairs: (K, 2) index pairs into the *associated* poses.
        translation_errors: (K,) metres. rotation_errors_deg: (K,) degrees.
    """

    delta_m: float
    translation: ErrorStats
    rotation_deg: ErrorStats
    pairs: np.ndarray
    translation_errors: np.ndarray
    rotation_errors_deg: np.ndarray

    def to_json(self) -> dict:
        return {"delta_m": self.delta_m, "translation_m": self.translation.to_json(),
                "rotation_deg": self.rotation_deg.to_json()}


def relative_pose_error(est: CameraTrajectory, ref: CameraTrajectory, delta_m: float, *, max_diff: float = 0.01,
                        all_pairs: bool = False, rel_delta_tol: float = 0.1,
                        pairs_from: str = "estimate") -> RpeResult:
    """RPE of ``est`` against ``ref`` over ``delta_m`` metres of path (see the module docstring).

    Args:
        max_diff: association tolerance, seconds.
        all_pairs: evo ``--all_pairs`` (tolerance ``rel_delta_tol * delta_m``).
        pairs_from: "estimate" (evo's default) or "reference" (evo ``--pairs_from_reference``).
    """
    if not delta_m > 0:
        raise SettingsError(f"delta_m must be positive, got {delta_m}")
    if pairs_from not in ("estimate", "reference"):
        raise SettingsError(f"pairs_from must be 'estimate' or 'reference', got {pairs_from!r}")
    i_est, i_ref = associate(est.t, ref.t, max_diff)
    P, Q = est.T_w_c[i_est], ref.T_w_c[i_ref]
    source = P if pairs_from == "estimate" else Q
    pairs = np.asarray(pairs_by_path(source[:, :3, 3], delta_m, rel_delta_tol * delta_m, all_pairs),
                       dtype=np.int64).reshape(-1, 2)
    if len(pairs) == 0:
        empty = np.zeros(0)
        return RpeResult(delta_m, ErrorStats.of(empty), ErrorStats.of(empty), pairs, empty, empty)
    i, j = pairs[:, 0], pairs[:, 1]
    Q_rel = np.linalg.inv(Q[i]) @ Q[j]
    P_rel = np.linalg.inv(P[i]) @ P[j]
    E = np.linalg.inv(Q_rel) @ P_rel
    t_err = np.linalg.norm(E[:, :3, 3], axis=1)
    r_err = np.degrees(Rotation.from_matrix(E[:, :3, :3]).magnitude())
    return RpeResult(delta_m, ErrorStats.of(t_err), ErrorStats.of(r_err), pairs, t_err, r_err)


__all__ = [
    "AteResult", "CameraTrajectory", "ErrorStats", "RpeResult", "absolute_trajectory_error", "associate",
    "pairs_by_path", "read_trajectory_tum", "relative_pose_error", "umeyama_alignment", "write_trajectory_tum",
]
