"""The variants ``vio-depth eval`` compares, and their names on the command line.

=======================================  =============================================================
name                                      what rescales each frame's disparity
=======================================  =============================================================
``oracle``                                least squares of ``1/gt`` on ``d`` over all ground-truth pixels
                                          (the best any per-frame rescaling can do)
``lidar:N``                               our pipeline with N simulated LiDAR beams from the ground truth
                                          (the paper's 1 / 16 / 32 / 64 beams)
``sfm[:MATCHER][:POSES]``                 our pipeline: triangulated points (default ``sift``, ``gt``)
``sfm-no-ransac[:MATCHER][:POSES]``       the same points, plain least squares per frame (no RANSAC, no
                                          fallback, no filter): the paper's RANSAC ablation
``fixed``                                 one ``(alpha, beta)`` for the whole sequence, least squares over
                                          every evaluated frame's ground truth: the paper's ablation
``paper-reference``                       the published code's choices (:mod:`vio_depth.baselines`)
=======================================  =============================================================

Groups: ``paper`` = ``oracle, lidar:1, lidar:16, lidar:32, lidar:64, sfm, sfm-no-ransac,
fixed, paper-reference`` (the default); ``all`` adds ``sfm`` with every learned matcher and
with IMU poses.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

from matchers import MATCHER_PRESETS
from vio_core.errors import SettingsError

from ..pipeline import POSE_PRESETS


class VariantKind(str, enum.Enum):
    ORACLE = "oracle"
    LIDAR = "lidar"
    SFM = "sfm"
    SFM_NO_RANSAC = "sfm-no-ransac"
    FIXED = "fixed"
    PAPER_REFERENCE = "paper-reference"

    @property
    def uses_pipeline(self) -> bool:
        """Runs our streaming pipeline over the frame range (needs every frame, in order)."""
        return self in (VariantKind.LIDAR, VariantKind.SFM, VariantKind.SFM_NO_RANSAC)


#: the paper's simulated LiDARs (beams)
PAPER_BEAMS = (1, 16, 32, 64)


@dataclass(frozen=True)
class Variant:
    """One variant (see the module docstring).

    Attributes:
        kind: :class:`VariantKind`.
        beams: LiDAR beams (``LIDAR`` only).
        matcher: matcher preset (``SFM`` / ``SFM_NO_RANSAC``; "" otherwise).
        poses: pose-source preset (``SFM`` / ``SFM_NO_RANSAC``; "" otherwise).
    """

    kind: VariantKind
    beams: int = 0
    matcher: str = ""
    poses: str = ""

    @property
    def name(self) -> str:
        """Canonical name: defaults left out (``sfm``, ``sfm:disk+lightglue``, ``sfm:imu``, ``lidar:16``)."""
        if self.kind == VariantKind.LIDAR:
            return f"lidar:{self.beams}"
        if self.kind in (VariantKind.SFM, VariantKind.SFM_NO_RANSAC):
            parts = [self.kind.value]
            if self.matcher != MATCHER_PRESETS.default:
                parts.append(self.matcher)
            if self.poses != POSE_PRESETS.default:
                parts.append(self.poses)
            return ":".join(parts)
        return self.kind.value

    def __str__(self) -> str:
        return self.name


def parse_variant(text: str) -> Variant:
    """A :class:`Variant` from its name (case-insensitive, surrounding blanks ignored).

    Raises:
        SettingsError: unknown kind, bad beam count, or an unknown / repeated matcher or
            pose-source name (the valid names are listed).
    """
    raw = str(text).strip().lower()
    head, _, rest = raw.partition(":")
    kinds = {k.value: k for k in VariantKind}
    if head not in kinds:
        raise SettingsError(f"unknown variant {text!r}; valid: oracle, lidar:N, sfm[:MATCHER][:POSES], "
                            "sfm-no-ransac[:MATCHER][:POSES], fixed, paper-reference (groups: paper, all)")
    kind = kinds[head]
    if kind == VariantKind.LIDAR:
        if not rest.isdigit() or int(rest) < 1:
            raise SettingsError(f"variant {text!r}: expected lidar:N with N >= 1 beams")
        return Variant(kind, beams=int(rest))
    if kind in (VariantKind.SFM, VariantKind.SFM_NO_RANSAC):
        matcher, poses = MATCHER_PRESETS.default, POSE_PRESETS.default
        seen = set()
        matchers, poses_names = set(MATCHER_PRESETS), set(POSE_PRESETS)  # (a Presets raises on unknown keys)
        for token in filter(None, rest.split(":")):
            if token in matchers and "matcher" not in seen:
                matcher, _ = token, seen.add("matcher")
            elif token in poses_names and "poses" not in seen:
                poses, _ = token, seen.add("poses")
            else:
                raise SettingsError(f"variant {text!r}: {token!r} is not a (first) matcher "
                                    f"({', '.join(MATCHER_PRESETS)}) or pose source ({', '.join(POSE_PRESETS)})")
        return Variant(kind, matcher=matcher, poses=poses)
    if rest:
        raise SettingsError(f"variant {text!r}: {head} takes no options")
    return Variant(kind)


def variant_groups() -> dict[str, tuple[str, ...]]:
    """Group name -> variant names (``paper``, ``all``)."""
    paper = ("oracle", *(f"lidar:{b}" for b in PAPER_BEAMS), "sfm", "sfm-no-ransac", "fixed", "paper-reference")
    learned = tuple(f"sfm:{m}" for m in MATCHER_PRESETS if m != MATCHER_PRESETS.default)
    return {"paper": paper, "all": paper + learned + ("sfm:imu",)}


def parse_variants(specs) -> list[Variant]:
    """Variants from names and group names (comma-separated or a list), duplicates dropped, order kept.

    Raises:
        SettingsError: an unknown name, or nothing given.
    """
    items = [specs] if isinstance(specs, str) else list(specs)
    names = [t for s in items for t in str(s).split(",") if t.strip()]
    if not names:
        raise SettingsError("no variant given (e.g. --variants paper, or oracle,sfm,paper-reference)")
    groups = variant_groups()
    out: dict[str, Variant] = {}
    for name in names:
        for one in groups.get(name.strip().lower(), (name,)):
            v = parse_variant(one)
            out.setdefault(v.name, v)
    return list(out.values())
