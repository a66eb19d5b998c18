"""Where a frame's metric points come from: the ``--points`` option of the pipeline.

``sfm`` (two-view triangulation) and ``landmarks`` (a multi-view keyframe window) come from
the images; ``lidar:<beams>`` and ``random:<count>`` are sampled from ground-truth depth by
:mod:`vio_depth.evaluation.reference_points` (an evaluation tool: the paper's simulated
LiDAR and random samples).
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

from vio_core.errors import InputError, SettingsError, UnknownNameError

from ..evaluation import lidar_beams, random_samples

POINT_SPEC_FORMS = ("sfm", "landmarks", "vio", "lidar:<beams>", "random:<count>")


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
