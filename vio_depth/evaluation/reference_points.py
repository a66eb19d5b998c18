"""Reference sparse metric points taken from ground-truth depth, for comparison with SfM.

The paper evaluates its rescaling with simulated low-resolution LiDARs ("evenly selecting
as many horizontal lines in the ground truth depth maps as the number of beams") and with
N random ground-truth samples. Selecting one of these as the point source instead of the
SfM front end (``--points lidar:16``, ``--points random:500``) compares SfM with them on the
same frames. Both need ground-truth depth and are an evaluation tool, not a sensor model.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from vio_core.checks import check_image
from vio_core.errors import InputError, SettingsError, UnknownNameError

POINT_SPEC_FORMS = ("sfm", "landmarks", "vio", "lidar:<beams>", "random:<count>")


def _valid_gt(gt_depth) -> tuple[np.ndarray, np.ndarray]:
    gt = check_image("gt_depth", gt_depth)
    with np.errstate(invalid="ignore"):
        valid = np.isfinite(gt) & (gt > 0)
    return gt, valid


def beam_rows(gt_depth, n_beams: int, over_valid_rows: bool = True) -> np.ndarray:
    """Image rows of a simulated ``n_beams``-beam LiDAR.

    The band of rows ``[r0, r1]`` (with ``h = r1 - r0 + 1`` rows) is split into ``n_beams``
    equal parts and each beam takes the row containing the centre of its part::

        row_k = r0 + floor((k + 0.5) * h / n_beams),   k = 0 .. n_beams - 1

    so 1 beam is the middle row of the band. With ``over_valid_rows`` the band is from the
    first to the last row holding any valid ground truth (KITTI's projected LiDAR covers only
    the lower part of the image); otherwise it is the whole image height.

    Args:
        gt_depth: (H, W) metres, 0 = invalid.
        n_beams: number of beams, 1 <= n_beams <= h.
        over_valid_rows: see above.

    Returns:
        (n_beams,) int64 rows, strictly increasing.

    Raises:
        InputError: no valid ground truth, or more beams than rows in the band.
    """
    gt, valid = _valid_gt(gt_depth)
    if n_beams < 1:
        raise InputError(f"lidar: n_beams must be >= 1, got {n_beams}")
    if over_valid_rows:
        rows = np.flatnonzero(valid.any(axis=1))
        if len(rows) == 0:
            raise InputError("lidar: the ground-truth depth has no valid pixel")
        r0, r1 = int(rows[0]), int(rows[-1])
    else:
        r0, r1 = 0, gt.shape[0] - 1
    h = r1 - r0 + 1
    if n_beams > h:
        raise InputError(f"lidar: {n_beams} beams need at least as many rows, the band has {h}")
    return r0 + np.floor((np.arange(n_beams) + 0.5) * h / n_beams).astype(np.int64)


def lidar_beams(gt_depth, n_beams: int, over_valid_rows: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Every valid ground-truth pixel on the rows of :func:`beam_rows`.

    Args:
        gt_depth: (H, W) metres, 0 = invalid.
        n_beams: number of beams (1, 16, 32, 64 in the paper).
        over_valid_rows: see :func:`beam_rows`.

    Returns:
        uv: (N, 2) float64 px, ``(column, row)`` at pixel centres, row-major order.
        depth: (N,) float64 metres.
    """
    gt, valid = _valid_gt(gt_depth)
    rows = beam_rows(gt, n_beams, over_valid_rows)
    sub = valid[rows]
    r_idx, cols = np.nonzero(sub)
    r = rows[r_idx]
    uv = np.stack([cols, r], axis=1).astype(np.float64)
    return uv, gt[r, cols].astype(np.float64)


def random_samples(gt_depth, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` distinct valid ground-truth pixels drawn uniformly (all of them if fewer).

    Args:
        gt_depth: (H, W) metres, 0 = invalid.
        n: number of samples (>= 1).
        seed: seed of the draw.

    Returns:
        uv: (M, 2) float64 px ``(column, row)``, ``M = min(n, valid pixels)``, row-major order.
        depth: (M,) float64 metres.
    """
    if n < 1:
        raise InputError(f"random: the number of samples must be >= 1, got {n}")
    gt, valid = _valid_gt(gt_depth)
    flat = np.flatnonzero(valid)
    if len(flat) > n:
        flat = np.sort(np.random.default_rng(seed).choice(flat, size=n, replace=False))
    rows, cols = np.divmod(flat, gt.shape[1])
    uv = np.stack([cols, rows], axis=1).astype(np.float64)
    return uv, gt.reshape(-1)[flat].astype(np.float64)


class PointSourceKind(str, enum.Enum):
    SFM = "sfm"  # triangulated by the structure-from-motion front end, two views at a time
    LANDMARKS = "landmarks"  # multi-view landmarks refined over a keyframe window (gtsam)
    VIO = "vio"  # the odometry's own landmarks (--poses vio), with their marginal covariances
    LIDAR = "lidar"  # simulated LiDAR beams from ground truth
    RANDOM = "random"  # random ground-truth samples


@dataclass(frozen=True)
class PointSourceSpec:
    """Where a frame's metric points come from (``--points``; :func:`parse_points_spec` parses it).

    Attributes:
        kind: :class:`PointSourceKind` (a name is accepted in any case and normalised here,
            once: ``"SFM"`` is ``sfm``).
        count: beams (LIDAR) or samples (RANDOM); None (or 0) for SFM.
        seed: seed of the RANDOM samples (frame ``k`` uses ``seed + k``).
    """

    kind: PointSourceKind = PointSourceKind.SFM
    count: int | None = None
    seed: int = 0

    def __post_init__(self):
        kind = self.kind
        if not isinstance(kind, PointSourceKind):
            try:
                kind = PointSourceKind(str(kind).strip().lower())
            except ValueError:
                raise UnknownNameError("point source", str(self.kind), [k.value for k in PointSourceKind]) from None
            object.__setattr__(self, "kind", kind)
        forms = ", ".join(POINT_SPEC_FORMS)
        if kind in (PointSourceKind.SFM, PointSourceKind.LANDMARKS, PointSourceKind.VIO):
            if self.count not in (None, 0):
                raise SettingsError(f"point source '{kind.value}' takes no count (valid forms: {forms})")
            object.__setattr__(self, "count", None)
        elif isinstance(self.count, bool) or not isinstance(self.count, int) or self.count < 1:
            what = "beams" if kind == PointSourceKind.LIDAR else "samples"
            raise SettingsError(f"point source '{kind.value}' needs a positive number of {what}, e.g. "
                                f"{kind.value}:{16 if kind == PointSourceKind.LIDAR else 500} (valid forms: {forms})")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise SettingsError(f"point source seed must be a non-negative integer, got {self.seed!r}")

    @property
    def uses_ground_truth(self) -> bool:
        return self.kind in (PointSourceKind.LIDAR, PointSourceKind.RANDOM)

    @property
    def triangulated(self) -> bool:
        """Points from the images (``sfm``, ``landmarks``), not sampled from ground truth."""
        return not self.uses_ground_truth

    def __str__(self) -> str:
        return self.kind.value if self.count is None else f"{self.kind.value}:{self.count}"

    def sample(self, gt_depth, frame_index: int = 0) -> tuple[np.ndarray, np.ndarray]:
        """``(uv (N, 2) px, depth (N,) metres)`` from ``gt_depth`` ((H, W) metres, 0 = invalid);
        RANDOM samples are seeded with ``seed + frame_index``.

        Raises:
            InputError: for ``sfm`` (its points come from the SfM front end, not from here).
        """
        if self.kind == PointSourceKind.LIDAR:
            return lidar_beams(gt_depth, self.count)
        if self.kind == PointSourceKind.RANDOM:
            return random_samples(gt_depth, self.count, self.seed + frame_index)
        raise InputError(f"the {self.kind.value!r} point source is triangulated by the pipeline, "
                         "not sampled from ground truth")


def parse_points_spec(spec: str, seed: int = 0) -> PointSourceSpec:
    """Parse ``"sfm"``, ``"lidar:<beams>"`` or ``"random:<count>"`` (case-insensitive).

    Raises:
        UnknownNameError: unknown source name (lists the valid forms).
        SettingsError: missing, malformed or non-positive count (lists the valid forms).
    """
    text = str(spec).strip().lower()
    name, sep, count_text = text.partition(":")
    forms = ", ".join(POINT_SPEC_FORMS)
    try:
        kind = PointSourceKind(name)
    except ValueError:
        raise UnknownNameError("point source", str(spec), POINT_SPEC_FORMS) from None
    if kind in (PointSourceKind.SFM, PointSourceKind.LANDMARKS, PointSourceKind.VIO):
        if sep:
            raise SettingsError(f"point source {spec!r}: '{kind.value}' takes no count (valid forms: {forms})")
        return PointSourceSpec(kind, seed=seed)
    if not sep or not count_text.strip().isdigit():
        what = "beams" if kind == PointSourceKind.LIDAR else "samples"
        raise SettingsError(f"point source {spec!r}: '{kind.value}' needs a positive number of {what}, "
                            f"e.g. {kind.value}:{16 if kind == PointSourceKind.LIDAR else 500} (valid forms: {forms})")
    return PointSourceSpec(kind, int(count_text), seed)
