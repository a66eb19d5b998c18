"""What every evaluation task opens: the sequence, its frame range, the disparity and the mask.

A task's settings are the JSON of :meth:`~vio_depth.experiments.plan.ResolvedEntry.task_settings`;
:func:`open_task` turns them back into objects in whatever process runs the task.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vio_core.errors import InputError

from .._version import __version__
from ..disparity import CachedDisparitySource, DisparitySettings, DisparitySource, cache_key, create_disparity_source
from ..evaluation import EvalMask
from ..frame import Frame
from ..io import Sequence, open_sequence


class FrameRange(Sequence):
    """Frames ``start .. stop-1`` of ``base`` as a sequence of their own (position 0 = frame ``start``).

    Frames keep their index in ``base`` (``frame.index``), so seeds and records are those
    of the whole sequence; only the positions start at 0.
    """

    def __init__(self, base: Sequence, start: int, stop: int):
        if not 0 <= start < stop <= len(base):
            raise InputError(f"FrameRange: need 0 <= {start} < {stop} <= {len(base)}")
        self.base, self.start, self.stop = base, int(start), int(stop)
        super().__init__(base.root, base.name, base.camera, base.imu, base.disparity)
        self.format_name = base.format_name
        self.imu_missing_reason = base.imu_missing_reason

    def __len__(self) -> int:
        return self.stop - self.start

    @property
    def has_gt_depth(self) -> bool:
        return self.base.has_gt_depth

    def frame(self, index: int) -> Frame:
        return self.base.frame(self.start + index)

    def position(self, frame_index: int) -> int:
        """Position in this range of frame ``frame_index`` of the base sequence."""
        return frame_index - self.start


def disparity_settings(kind: str, seed: int) -> DisparitySettings:
    """``sequence`` -> the sequence's own; ``simulated`` -> SIMULATED from ground truth with ``seed``."""
    return DisparitySettings() if kind == "sequence" else DisparitySettings(source="simulated", seed=int(seed))


def open_disparity(sequence: Sequence, kind: str, seed: int, cache_dir: str | None) -> DisparitySource:
    """The entry's disparity source, behind a :class:`~vio_depth.disparity.CachedDisparitySource` when
    ``cache_dir`` is given (key: sequence path, disparity settings, package version)."""
    settings = disparity_settings(kind, seed)
    source = create_disparity_source(settings, sequence)
    if cache_dir is None:
        return source
    spec = None if sequence.disparity is None else sequence.disparity.to_json()
    key = cache_key(str(Path(sequence.root).resolve()), sequence.format_name, kind, int(seed), spec, __version__)
    return CachedDisparitySource(source, cache_dir, key)


@dataclass
class TaskContext:
    """The opened inputs of a task.

    Attributes:
        sequence: the whole sequence (the paper-reference pairs with any earlier frame).
        frames: the processed range (:class:`FrameRange`).
        evaluate: indices (in ``sequence``) of the scored frames, increasing.
        mask: the scored pixels.
        disparity: the disparity source (cached).
        settings: the task settings (JSON).
    """

    sequence: Sequence
    frames: FrameRange
    evaluate: tuple[int, ...]
    mask: EvalMask
    disparity: DisparitySource
    settings: dict

    @property
    def seed(self) -> int:
        return int(self.settings.get("seed", 0))

    def gt(self, frame: Frame) -> np.ndarray | None:
        """The frame's ground truth with the mask's crop applied (None without ground truth)."""
        gt = frame.gt_depth()
        return None if gt is None else self.mask.apply(gt)


def open_task(path: str, settings: dict) -> TaskContext:
    """Open the sequence at ``path`` with the task ``settings`` (see the module docstring)."""
    seq = open_sequence(path, format=settings.get("format"))
    m = settings["mask"]
    mask = EvalMask(float(m["min_depth"]), float(m["max_depth"]), str(m["crop"]))
    disparity = open_disparity(seq, settings["disparity"], int(settings.get("seed", 0)),
                               settings.get("disparity_cache"))
    return TaskContext(seq, FrameRange(seq, int(settings["start"]), int(settings["stop"])),
                       tuple(int(i) for i in settings["evaluate"]), mask, disparity, settings)
