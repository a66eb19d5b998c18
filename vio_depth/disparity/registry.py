"""Choosing a disparity source by name: the sequence's own, files, SIMULATED, or a model."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from vio_core.errors import InputError, SettingsError, lookup

from ..models import DepthAnythingSettings
from .base import DisparityKind, DisparitySource, DisparitySpec
from .densify import GtDisparitySettings
from .model import ModelDisparity
from .simulation import disparity_preset
from .sources import FileDisparity, SimulatedDisparitySource
from .validity import MIN_VALID_FRACTION

#: the user's choices (``--disparity``); "sequence" = what the sequence carries
DISPARITY_CHOICES = ("sequence", "files", "simulated", "model")


@dataclass(frozen=True)
class DisparitySettings:
    """Which disparity the pipeline rescales (``vio-depth run --disparity ...``).

    Attributes:
        source: one of :data:`DISPARITY_CHOICES`: ``"sequence"`` (the sequence's own maps:
            files, or for the bundled samples a SIMULATED disparity), ``"files"`` (``path``
            holds ``<image stem>.npy`` per frame), ``"simulated"`` (SIMULATED from the
            ground-truth depth, densified first: for datasets without network outputs), or
            ``"model"`` (Depth Anything weights at ``path``).
        path: the folder (files) or the weights (model); empty otherwise.
        seed: seed of the SIMULATED disparity (source "simulated").
        simulation: preset name of the simulation model ("default", "clean", "hard").
        model: how the network runs (source "model").
        model_variant: for a renamed original ``.pth`` (see docs/models.md), else "".
        min_valid_fraction: a map with fewer finite pixels than this fraction gives the
            frame status ``invalid_disparity`` (:mod:`vio_depth.disparity.validity`).
    """

    source: str = "sequence"
    path: str = ""
    seed: int = 0
    simulation: str = "default"
    model: DepthAnythingSettings = field(default_factory=DepthAnythingSettings)
    model_variant: str = ""
    min_valid_fraction: float = MIN_VALID_FRACTION

    def __post_init__(self):
        source = str(self.source).lower()
        lookup("disparity source", source, dict.fromkeys(DISPARITY_CHOICES))
        object.__setattr__(self, "source", source)
        if source in ("files", "model") and not self.path:
            raise SettingsError(f"disparity source {source!r} needs a path "
                                f"({'--disparity-dir DIR' if source == 'files' else '--model PATH'})")
        if source in ("sequence", "simulated") and self.path:
            raise SettingsError(f"disparity source {source!r} takes no path (got {self.path!r})")
        if isinstance(self.seed, bool) or not isinstance(self.seed, int) or self.seed < 0:
            raise SettingsError(f"disparity seed must be a non-negative integer, got {self.seed!r}")
        disparity_preset(self.simulation)  # unknown name -> UnknownNameError listing the valid ones
        if not 0.0 <= self.min_valid_fraction <= 1.0:
            raise SettingsError(f"disparity min_valid_fraction must be in [0, 1], got {self.min_valid_fraction!r}")


def source_for_spec(spec: DisparitySpec, root) -> DisparitySource:
    """The source for a sequence's declared disparity (``root``: the sequence folder)."""
    if spec.kind == DisparityKind.FILES:
        return FileDisparity(Path(root) / spec.folder, required=True)
    return SimulatedDisparitySource(spec.seed, spec.model)


def create_disparity_source(settings: DisparitySettings, sequence=None) -> DisparitySource:
    """The disparity source chosen by ``settings`` for ``sequence``.

    Raises:
        InputError: the sequence carries no disparity ("sequence"), has no ground-truth
            depth to simulate from ("simulated"), or a path does not exist.
        MissingDependencyError: "model" without torch / transformers / onnxruntime.
    """
    if settings.source == "sequence":
        spec = getattr(sequence, "disparity", None)
        if spec is None:
            where = getattr(sequence, "root", "the sequence")
            raise InputError(f"{where}: the sequence carries no disparity maps; choose --disparity files "
                             "--disparity-dir DIR (one <image stem>.npy per frame), --disparity model "
                             "--model PATH, or --disparity simulated (SIMULATED from ground-truth depth)")
        return source_for_spec(spec, sequence.root)
    if settings.source == "files":
        return FileDisparity(settings.path)
    if settings.source == "simulated":
        if sequence is not None and not sequence.has_gt_depth:
            raise InputError(f"{sequence.root}: --disparity simulated needs ground-truth depth, "
                             "which this sequence lacks")
        return SimulatedDisparitySource(settings.seed, densify=GtDisparitySettings(model=disparity_preset(settings.simulation)))
    return ModelDisparity.from_path(settings.path, settings.model, variant=settings.model_variant or None)
