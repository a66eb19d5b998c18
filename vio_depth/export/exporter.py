"""The optional outputs of one run, written frame by frame and completed at the end.

:class:`RunExporter` is driven by the run loop: :meth:`RunExporter.add_frame` after each
frame (again for a frame the offline backfill replaced: files are overwritten and the
merged map keeps the newest points), :meth:`RunExporter.finish` once at the end. Files, in
the run's output folder (each written under a temporary name and renamed):

* ``depth_npy/<stem>.npy``     float32 metres, NaN invalid (``npy``)
* ``preview/<stem>.png``       colourised depth, one colour range for the whole run (``preview``)
* ``error/<stem>.png``         signed relative error against ground truth (``preview``, with GT)
* ``preview/legend.json``      colormap, scale and range of those previews
* ``ply/sparse/<stem>.ply``    the frame's metric points, world frame (``ply.sparse``)
* ``ply/sparse_map.ply``       all frames' points merged, world frame (``ply.sparse``)
* ``ply/dense/<stem>.ply``     back-projected depth map, world frame (``ply.dense_stride``)
* ``thumbs/<stem>_image.jpg``, ``thumbs/<stem>_{preview,error}.png`` and ``thumbs/legend.json``:
  the best, median and worst frames, small, for ``vio-depth report`` (``thumbnails``)

Previews are written in :meth:`finish`, because the run-wide colour range is known only
then; their depth comes from ``depth_npy/`` when written, else from ``depth/<stem>.png``
(1/256 m steps, far finer than a colour step).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from ..io.depth_png import read_depth_png, write_bytes_atomic
from ..rescale import depth_sigma_map
from .colormap import ERROR_LEVELS
from .npy import read_depth_npy, write_depth_npy
from .ply import PointCloud, dense_cloud, sparse_cloud, write_ply
from .preview import (
    ERROR_COLORMAP,
    PreviewSettings,
    depth_percentiles,
    depth_preview,
    error_preview,
    run_depth_range,
    write_jpeg_rgb,
    write_png_rgb,
)
from .selection import select_frames
from .settings import ExportSettings


@dataclass
class ExportReport:
    """What :class:`RunExporter` wrote: file counts per kind, and notes on what it skipped."""

    counts: dict = field(default_factory=dict)
    notes: list = field(default_factory=list)
    depth_range: tuple[float, float] | None = None

    def add(self, kind: str, n: int = 1) -> None:
        self.counts[kind] = self.counts.get(kind, 0) + n

    def to_json(self) -> dict:
        out = {"counts": dict(self.counts), "notes": list(self.notes)}
        if self.depth_range is not None:
            out["preview_depth_range_m"] = [round(v, 4) for v in self.depth_range]
        return out


def legend_json(style: PreviewSettings, depth_range: tuple[float, float]) -> dict:
    """The ``legend.json`` next to colourised images: how to read their colours."""
    return {
        "colormap": style.colormap,
        "scale": style.scale,
        "depth_range_m": [float(depth_range[0]), float(depth_range[1])],
        "near_is_lut_index": 255,
        "invalid_rgb": [int(c) for c in style.invalid_rgb],
        "error_colormap": ERROR_COLORMAP,
        "error_range": float(style.error_range),
        "error_levels": ERROR_LEVELS,
        "error_definition": "(depth - gt) / gt; blue = too near, red = too far",
    }


def resize_to_width(rgb: np.ndarray, width: int, nearest: bool) -> np.ndarray:
    """``rgb: (H, W, 3)`` uint8 resized to ``width`` px (aspect kept). ``nearest`` keeps exact
    colours (for colour-coded maps); otherwise area averaging (photos)."""
    h, w = rgb.shape[:2]
    if w <= width:
        return rgb
    height = max(1, round(h * width / w))
    return cv2.resize(rgb, (width, height), interpolation=cv2.INTER_NEAREST if nearest else cv2.INTER_AREA)


class RunExporter:
    """Writes the optional outputs chosen in ``settings`` into ``out_dir`` (see module doc)."""

    def __init__(self, out_dir, settings: ExportSettings):
        self.out_dir = Path(out_dir)
        self.settings = settings
        self.report = ExportReport()
        self._with_depth: dict[int, str] = {}  # frame index -> stem, frames with depth
        self._ranges: dict[int, tuple[float, float] | None] = {}
        self._sparse: dict[int, PointCloud] = {}
        self._no_pose: set[int] = set()
        folders = []
        if settings.npy:
            folders.append("depth_npy")
        if settings.ply.sparse:
            folders.append("ply/sparse")
        if settings.ply.dense_stride is not None:
            folders.append("ply/dense")
        for f in folders:
            (self.out_dir / f).mkdir(parents=True, exist_ok=True)

    # ------------------------------------------------------------------ per frame
    def add_frame(self, frame, result, write: bool = True) -> None:
        """Write the per-frame outputs of ``result`` (a ``FrameResult``) for ``frame`` (a ``Frame``).

        ``write=False`` only records what :meth:`finish` needs (a resumed run replays the
        frames whose files already exist)."""
        s = self.settings
        depth = result.depth
        if depth is not None:
            self._with_depth[frame.index] = frame.stem
            if s.npy and write:
                write_depth_npy(self.out_dir / "depth_npy" / f"{frame.stem}.npy", depth)
            if s.preview is not None or s.thumbnails:
                self._ranges[frame.index] = depth_percentiles(depth, s.style.percentiles)
        if not s.ply.any:
            return
        uv = result.points_uv
        want_sparse = s.ply.sparse and uv is not None and len(uv) > 0
        want_dense = depth is not None and s.ply.wants_dense(frame.index)
        if not (want_sparse or want_dense):
            return
        if frame.T_w_c is None:
            self._no_pose.add(frame.index)
            return
        self._no_pose.discard(frame.index)
        if not (want_sparse or write):
            return
        image = frame.image()
        if want_sparse:
            cloud = sparse_cloud(frame.camera, frame.T_w_c, uv, result.points_depth, image=image,
                                 sigma_depth=getattr(result, "points_sigma", None),
                                 inlier=getattr(result, "points_inlier", None), frame_index=frame.index)
            self._sparse[frame.index] = cloud
            if write:
                write_ply(self.out_dir / "ply" / "sparse" / f"{frame.stem}.ply", cloud,
                          comments=(f"frame {frame.index} stem {frame.stem}: sparse metric points",))
        if want_dense and write:
            sigma = None
            if result.disparity is not None and result.fit is not None:
                sigma = depth_sigma_map(result.disparity, result.fit)
            cloud = dense_cloud(frame.camera, frame.T_w_c, depth, image=image, sigma_map=sigma,
                                stride=s.ply.dense_stride, max_depth=s.ply.dense_max_depth, frame_index=frame.index)
            write_ply(self.out_dir / "ply" / "dense" / f"{frame.stem}.ply", cloud,
                      comments=(f"frame {frame.index} stem {frame.stem}: dense depth, stride {s.ply.dense_stride}",))

    # ------------------------------------------------------------------ end of run
    def finish(self, sequence, records) -> ExportReport:
        """Write the run-wide outputs (previews, merged map, thumbnails) and return what was written.

        Args:
            sequence: the run's sequence (ground truth and images of chosen frames are re-read).
            records: the per-frame JSON records of the run, in frame order.
        """
        s, rep = self.settings, self.report
        if s.npy:
            rep.add("depth_npy", len(self._with_depth))
        style = s.style
        depth_range = style.depth_range or run_depth_range(self._ranges.get(i) for i in sorted(self._with_depth))
        rep.depth_range = depth_range
        if s.preview is not None and depth_range is not None:
            self._write_previews(sequence, depth_range)
        if s.ply.sparse:
            counted = {i: c for i, c in sorted(self._sparse.items())}
            rep.add("ply_sparse_frames", len(counted))
            merged = PointCloud.concatenate(counted.values())
            (self.out_dir / "ply").mkdir(parents=True, exist_ok=True)
            write_ply(self.out_dir / "ply" / "sparse_map.ply", merged,
                      comments=(f"sparse map: {len(counted)} frames merged",))
            rep.add("ply_sparse_map_points", len(merged))
        if s.ply.dense_stride is not None:
            rep.add("ply_dense_frames", sum(1 for i in self._with_depth if s.ply.wants_dense(i) and i not in self._no_pose))
        if self._no_pose:
            rep.notes.append(f"{len(self._no_pose)} frame(s) without a camera-to-world pose got no point cloud")
        if s.thumbnails and depth_range is not None:
            self._write_thumbnails(sequence, records, depth_range)
        return rep

    def _depth(self, stem: str) -> np.ndarray:
        npy = self.out_dir / "depth_npy" / f"{stem}.npy"
        if npy.is_file():
            return read_depth_npy(npy)
        d = read_depth_png(self.out_dir / "depth" / f"{stem}.png")
        d[d <= 0] = np.nan
        return d

    def _write_previews(self, sequence, depth_range) -> None:
        style = self.settings.style
        (self.out_dir / "preview").mkdir(parents=True, exist_ok=True)
        errors = 0
        for i, stem in sorted(self._with_depth.items()):
            depth = self._depth(stem)
            write_png_rgb(self.out_dir / "preview" / f"{stem}.png", depth_preview(depth, depth_range, style))
            gt = sequence[i].gt_depth() if sequence.has_gt_depth else None
            if gt is not None:
                if errors == 0:
                    (self.out_dir / "error").mkdir(parents=True, exist_ok=True)
                write_png_rgb(self.out_dir / "error" / f"{stem}.png", error_preview(depth, gt, style))
                errors += 1
        legend = (json.dumps(legend_json(style, depth_range), indent=2) + "\n").encode()
        write_bytes_atomic(self.out_dir / "preview" / "legend.json", legend)
        self.report.add("previews", len(self._with_depth))
        if errors:
            self.report.add("error_maps", errors)

    def _write_thumbnails(self, sequence, records, depth_range) -> None:
        selection = select_frames(records)
        if selection is None:
            self.report.notes.append("no frame with depth: no thumbnails")
            return
        style, width = self.settings.style, self.settings.thumbnail_width
        folder = self.out_dir / "thumbs"
        folder.mkdir(parents=True, exist_ok=True)
        index_of = {stem: i for i, stem in self._with_depth.items()}
        for rec in selection.frames.values():
            stem = rec["stem"]
            i = index_of.get(stem, rec.get("frame"))
            frame = sequence[i]
            depth = self._depth(stem)
            write_jpeg_rgb(folder / f"{stem}_image.jpg", resize_to_width(frame.image(), width, False))
            write_png_rgb(folder / f"{stem}_preview.png",
                          resize_to_width(depth_preview(depth, depth_range, style), width, True))
            gt = frame.gt_depth() if sequence.has_gt_depth else None
            if gt is not None:
                write_png_rgb(folder / f"{stem}_error.png", resize_to_width(error_preview(depth, gt, style), width, True))
        write_bytes_atomic(folder / "legend.json",
                           (json.dumps(legend_json(style, depth_range), indent=2) + "\n").encode())
        self.report.add("thumbnails", len(selection.frames))
