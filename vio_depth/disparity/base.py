"""The disparity stage's contract: one source protocol, its kinds, and the map check.

A disparity source is a callable ``source(frame) -> (H, W) float32 | None`` with a ``kind``
(:class:`DisparityKind`) that outputs record, so that a result computed on a SIMULATED
disparity is always labelled as such. ``None`` means "no map for this frame" (the pipeline
then reports status ``no_disparity``); a malformed map raises :class:`InputError`.

A sequence declares the disparity it carries with a :class:`DisparitySpec`; the
registry (:mod:`vio_depth.disparity.registry`) turns a spec or the user's choice into a
source.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from vio_core.errors import InputError

from ..frame import Frame
from .simulation import DisparitySimulation, disparity_preset


class DisparityKind(str, enum.Enum):
    """Where a disparity map comes from (recorded in frames.jsonl and metrics.json)."""

    FILES = "files"  # read from <stem>.npy files (a network run elsewhere, or the sequence's own)
    SIMULATED = "simulated"  # SIMULATED from ground-truth depth: not a network prediction
    MODEL = "model"  # Depth Anything run by vio-depth on each image
    ARRAY = "array"  # handed over by the caller with each frame (Python API, ROS node)


@runtime_checkable
class DisparitySource(Protocol):
    """Gives each frame's affine-invariant disparity (bigger = nearer)."""

    kind: DisparityKind

    def __call__(self, frame: Frame) -> np.ndarray | None:
        """(H, W) float32 disparity of ``frame`` (NaN = invalid pixel), or None when absent."""


@runtime_checkable
class ExplainsMissing(Protocol):
    """A disparity source that can say why it has no map for a frame (a missing file, named)."""

    def missing_reason(self, frame: Frame) -> str:
        """One line: why ``source(frame)`` gave None."""


def missing_disparity_reason(source, frame: Frame) -> str:
    """Why ``source`` has no map for ``frame``: the source's own words when it can say
    (:class:`ExplainsMissing`: a file source names the missing file), else a general line."""
    if isinstance(source, ExplainsMissing):
        return source.missing_reason(frame)
    return "no disparity map for this frame"


@dataclass(frozen=True)
class DisparitySpec:
    """The disparity a sequence carries, as its loader declares it.

    Attributes:
        kind: :attr:`DisparityKind.FILES` (``folder`` of ``<stem>.npy``, relative to the
            sequence root) or :attr:`DisparityKind.SIMULATED` (SIMULATED from the
            ground-truth depth with ``seed`` and ``model``).
        folder: for FILES.
        seed: for SIMULATED, non-negative.
        model: for SIMULATED, the :class:`DisparitySimulation` parameters.
    """

    kind: DisparityKind
    folder: str | None = None
    seed: int | None = None
    model: DisparitySimulation | None = None

    def __post_init__(self):
        object.__setattr__(self, "kind", DisparityKind(self.kind))
        if self.kind == DisparityKind.FILES and not self.folder:
            raise InputError("a 'files' disparity needs a folder")
        if self.kind == DisparityKind.SIMULATED:
            if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
                raise InputError(f"simulated disparity seed must be a non-negative integer, got {self.seed!r}")
            if not isinstance(self.model, DisparitySimulation):
                raise InputError("a 'simulated' disparity needs its DisparitySimulation model")
        if self.kind in (DisparityKind.MODEL, DisparityKind.ARRAY):
            raise InputError(f"a sequence cannot carry a {self.kind.value!r} disparity")

    @classmethod
    def files(cls, folder: str = "disparity") -> "DisparitySpec":
        """Disparity stored as ``<folder>/<stem>.npy`` files."""
        return cls(DisparityKind.FILES, folder=folder)

    @classmethod
    def simulated(cls, seed: int, model: DisparitySimulation | None = None) -> "DisparitySpec":
        """SIMULATED disparity (seed + frame index; ``model`` default: the "default" preset)."""
        return cls(DisparityKind.SIMULATED, seed=seed, model=disparity_preset("default") if model is None else model)

    def to_json(self) -> dict:
        if self.kind == DisparityKind.FILES:
            return {"kind": "files", "folder": self.folder}
        return {"kind": "simulated", "seed": int(self.seed), "model": self.model.to_json()}


def check_disparity(disparity, frame: Frame, origin: str) -> np.ndarray:
    """Validate a disparity map for ``frame``: (H, W) matching the camera, float, no infinities.

    NaN marks invalid pixels and is kept. Returns the map as float32.

    Raises:
        InputError: wrong shape or dtype, or infinite values (the message names ``origin``).
    """
    d = np.asarray(disparity)
    cam = frame.camera
    if d.ndim != 2 or d.shape != (cam.height, cam.width):
        raise InputError(
            f"{origin}: disparity must be ({cam.height}, {cam.width}) to match the image, got {d.shape}"
        )
    if d.dtype.kind != "f":
        raise InputError(f"{origin}: disparity must be a float array, got dtype {d.dtype}")
    if np.isinf(d).any():
        raise InputError(f"{origin}: disparity contains infinite values")
    return d.astype(np.float32, copy=False)
