"""Which optional outputs a run writes (``vio-depth run --save-npy --save-preview --save-ply ...``)."""

from __future__ import annotations

from dataclasses import dataclass, field

from vio_core.errors import SettingsError

from .preview import PreviewSettings

#: default pixel step of dense clouds (1/16 of the pixels)
DEFAULT_DENSE_STRIDE = 4


@dataclass(frozen=True)
class PlySettings:
    """Point clouds to write.

    Attributes:
        sparse: per-frame sparse points ``ply/sparse/<stem>.ply`` and the merged map
            ``ply/sparse_map.ply`` (world frame).
        dense_stride: write ``ply/dense/<stem>.ply`` back-projecting every ``dense_stride``-th
            pixel, or None for no dense clouds.
        dense_frames: frame indices that get a dense cloud (None = every frame with depth).
        dense_max_depth: drop dense points deeper than this (metres), or None.
    """

    sparse: bool = False
    dense_stride: int | None = None
    dense_frames: tuple[int, ...] | None = None
    dense_max_depth: float | None = None

    def __post_init__(self):
        if self.dense_stride is not None and self.dense_stride < 1:
            raise SettingsError(f"dense stride must be >= 1, got {self.dense_stride}")
        if self.dense_max_depth is not None and not self.dense_max_depth > 0:
            raise SettingsError(f"dense max depth must be > 0 metres, got {self.dense_max_depth}")

    @property
    def any(self) -> bool:
        return self.sparse or self.dense_stride is not None

    def wants_dense(self, frame_index: int) -> bool:
        return self.dense_stride is not None and (self.dense_frames is None or frame_index in self.dense_frames)


@dataclass(frozen=True)
class ExportSettings:
    """Optional outputs of a run (all off by default).

    Attributes:
        npy: ``depth_npy/<stem>.npy``, float32 metres, NaN invalid (:mod:`.npy`).
        preview: ``preview/<stem>.png`` colourised depth, and ``error/<stem>.png`` against
            ground truth when the sequence has it (:mod:`.preview`), with these settings;
            None = no previews.
        ply: point clouds (:class:`PlySettings`).
        thumbnails: ``thumbs/``: image, preview and error-map thumbnails of the best, median
            and worst frames, for the report (``--report``).
        thumbnail_width: pixels.
        preview_style: colours of the thumbnails when ``preview`` is None.
    """

    npy: bool = False
    preview: PreviewSettings | None = None
    ply: PlySettings = field(default_factory=PlySettings)
    thumbnails: bool = False
    thumbnail_width: int = 320
    preview_style: PreviewSettings = field(default_factory=PreviewSettings)

    def __post_init__(self):
        if self.thumbnail_width < 16:
            raise SettingsError(f"thumbnail width must be >= 16 px, got {self.thumbnail_width}")

    @property
    def any(self) -> bool:
        return self.npy or self.preview is not None or self.ply.any or self.thumbnails

    @property
    def style(self) -> PreviewSettings:
        """Colours of previews and thumbnails."""
        return self.preview if self.preview is not None else self.preview_style


def parse_ply_spec(specs, frames: str | None = None, max_depth: float | None = None) -> PlySettings:
    """``--save-ply`` values -> :class:`PlySettings`.

    Args:
        specs: strings, each a comma-separated list of ``sparse``, ``dense`` or
            ``dense:STRIDE`` (e.g. ``["sparse,dense:8"]``); repeated flags accumulate.
        frames: ``--ply-frames``: frames that get dense clouds (:func:`parse_frame_list`), or None.
        max_depth: drop dense points beyond this many metres, or None.

    Raises:
        SettingsError: unknown item or bad stride.
    """
    if isinstance(specs, str):
        specs = [specs]
    sparse, stride = False, None
    for item in (x.strip() for s in specs for x in s.split(",")):
        if item == "sparse":
            sparse = True
        elif item == "dense":
            stride = DEFAULT_DENSE_STRIDE
        elif item.startswith("dense:"):
            try:
                stride = int(item.split(":", 1)[1])
            except ValueError:
                raise SettingsError(f"--save-ply: dense:STRIDE needs an integer stride, got {item!r}") from None
            if stride < 1:
                raise SettingsError(f"--save-ply: dense stride must be >= 1, got {item!r}")
        else:
            raise SettingsError(f"--save-ply: unknown item {item!r}; use sparse, dense or dense:STRIDE")
    if frames is not None and stride is None:
        raise SettingsError("--ply-frames selects frames for dense clouds: add --save-ply dense[:STRIDE]")
    return PlySettings(sparse=sparse, dense_stride=stride,
                       dense_frames=None if frames is None else parse_frame_list(frames),
                       dense_max_depth=max_depth)


def parse_frame_list(text: str) -> tuple[int, ...]:
    """Frame indices from ``"0,10,25"`` and/or ranges ``"START:STOP[:STEP]"`` (stop excluded),
    e.g. ``"0:120:10,7"``.

    Raises:
        SettingsError: not integers, negative, or an empty selection.
    """
    out: set[int] = set()
    try:
        for item in (x.strip() for x in text.split(",") if x.strip()):
            if ":" in item:
                parts = [int(p) for p in item.split(":")]
                if len(parts) not in (2, 3) or (len(parts) == 3 and parts[2] < 1):
                    raise ValueError
                out.update(range(*parts))
            else:
                out.add(int(item))
    except ValueError:
        raise SettingsError(f"frame list must be indices and START:STOP[:STEP] ranges, got {text!r}") from None
    if not out or min(out) < 0:
        raise SettingsError(f"frame list must select frames with indices >= 0, got {text!r}")
    return tuple(sorted(out))
