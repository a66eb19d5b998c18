"""What ``vio-depth eval`` evaluates: sequences with their options, and the frames of each.

A sequence argument is a path with optional options after ``@``::

    sample_sequences/street
    sample_sequences/room@indoor
    ../shared/data/7scenes_redkitchen@indoor,disparity=simulated,frames=0:120
    /data/kitti/2011_09_26/2011_09_26_drive_0002_sync@frames=0:200:5,name=drive_0002

Options (comma-separated; the command's flags give the defaults):

==================  ========================================================================
option              meaning
==================  ========================================================================
``outdoor``         profile (default): depth cap 80 m, pairing ``kitti``, paper-reference
                    preset ``kitti``, Garg crop for KITTI raw drives
``indoor``          profile: cap 10 m, pairing ``indoor``, paper-reference preset ``indoor``
``ddad``            profile: cap 80 m, pairing ``ddad``, paper-reference preset ``ddad``
``frames=A:B[:S]``  process frames ``A .. B-1`` in order; evaluate every ``S``-th of them
``disparity=X``     ``sequence`` (its own maps) or ``simulated`` (SIMULATED from ground truth)
``max-depth=M``     the depth cap in metres (overrides the profile)
``crop=C``          ``none``, ``garg`` or ``eigen`` (overrides the profile)
``pairing=P``       pairing preset of our pipeline (overrides the profile)
``paper=P``         paper-reference preset (overrides the profile)
``format=F``        the sequence format (default: detected)
``name=N``          the label in tables (default: the folder's name)
==================  ========================================================================

:func:`entries_from_split` turns a KITTI split file (the paper's Eigen test split) into one
entry per drive with exactly the listed frames to evaluate.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

from vio_core.errors import InputError, SettingsError, lookup

from ..baselines import PAPER_REFERENCE_PRESETS
from ..evaluation import CROPS, EvalMask
from ..io import open_sequence
from ..io.kitti_split import frame_indices, read_split_file, resolve_split
from ..keyframes import PAIRING_PRESETS


@dataclass(frozen=True)
class Profile:
    """Defaults of a kind of scene: the depth cap, the pairing presets and the KITTI crop."""

    max_depth: float
    pairing: str
    paper: str
    kitti_crop: str = "none"


PROFILES: dict[str, Profile] = {
    "outdoor": Profile(max_depth=80.0, pairing="kitti", paper="kitti", kitti_crop="garg"),
    "indoor": Profile(max_depth=10.0, pairing="indoor", paper="indoor"),
    "ddad": Profile(max_depth=80.0, pairing="ddad", paper="ddad"),
}
DISPARITY_OPTIONS = ("sequence", "simulated")
#: sequence formats that get the profile's KITTI crop
KITTI_FORMATS = ("kitti_raw",)


@dataclass(frozen=True)
class FrameSelection:
    """Frames ``start .. stop-1`` are processed in order; ``evaluate`` (indices) are scored.

    ``stop`` None = the end of the sequence; ``evaluate`` None = every ``step``-th frame of
    the range, starting at ``start``.
    """

    start: int = 0
    stop: int | None = None
    step: int = 1
    evaluate: tuple[int, ...] | None = None

    def __post_init__(self):
        if self.start < 0 or (self.stop is not None and self.stop <= self.start) or self.step < 1:
            raise SettingsError(f"frames: need 0 <= start < stop and step >= 1, "
                                f"got {self.start}:{self.stop}:{self.step}")

    @classmethod
    def parse(cls, text: str) -> "FrameSelection":
        """``A:B``, ``A:B:S``, ``A:`` or ``:B`` (as Python slices)."""
        parts = str(text).split(":")
        try:
            if len(parts) not in (2, 3):
                raise ValueError
            start = int(parts[0]) if parts[0] else 0
            stop = int(parts[1]) if parts[1] else None
            step = int(parts[2]) if len(parts) == 3 and parts[2] else 1
        except ValueError:
            raise SettingsError(f"frames={text!r}: expected A:B or A:B:S (e.g. 0:120:2)") from None
        return cls(start, stop, step)

    def resolve(self, n_frames: int) -> tuple[int, int, tuple[int, ...]]:
        """``(start, stop, evaluated indices)`` for a sequence of ``n_frames``; ``stop`` is trimmed to
        the last evaluated frame + 1 (later frames cannot change the scores).

        Raises:
            InputError: the selection lies outside the sequence or selects nothing.
        """
        stop = n_frames if self.stop is None else min(self.stop, n_frames)
        if self.evaluate is not None:
            bad = [i for i in self.evaluate if not 0 <= i < n_frames]
            if bad:
                raise InputError(f"frames {bad[:5]} are outside the sequence's {n_frames} frames")
            ev = tuple(sorted(set(self.evaluate)))
        else:
            ev = tuple(range(self.start, stop, self.step))
        if not ev:
            raise InputError(f"frames {self.describe()}: no frame of the sequence's {n_frames} selected")
        return min(self.start, ev[0]), ev[-1] + 1, ev

    def describe(self) -> str:
        if self.evaluate is not None:
            return f"{len(self.evaluate)} listed frames"
        stop = "end" if self.stop is None else self.stop - 1
        return f"{self.start}-{stop}" + (f", every {self.step}" if self.step > 1 else "")


@dataclass(frozen=True)
class SequenceEntry:
    """One sequence of an evaluation and its options (see the module docstring)."""

    path: str
    profile: str = "outdoor"
    frames: FrameSelection = field(default_factory=FrameSelection)
    disparity: str = "sequence"
    max_depth: float | None = None
    crop: str | None = None
    pairing: str | None = None
    paper: str | None = None
    format: str | None = None
    name: str | None = None

    def __post_init__(self):
        lookup("evaluation profile", self.profile, PROFILES)
        lookup("disparity option", self.disparity, dict.fromkeys(DISPARITY_OPTIONS))
        if self.crop is not None:
            lookup("evaluation crop", self.crop, CROPS)
        if self.pairing is not None:
            PAIRING_PRESETS[self.pairing]
        if self.paper is not None:
            lookup("paper-reference preset", self.paper, PAPER_REFERENCE_PRESETS)
        if self.max_depth is not None and not self.max_depth > 0:
            raise SettingsError(f"max-depth must be > 0, got {self.max_depth}")

    @property
    def label(self) -> str:
        return self.name or Path(self.path).name


_KEYS = {"frames", "disparity", "max-depth", "max_depth", "crop", "pairing", "paper", "format", "name"}


def parse_sequence_arg(text: str, defaults: SequenceEntry | None = None) -> SequenceEntry:
    """A :class:`SequenceEntry` from ``PATH[@option,...]`` on top of ``defaults`` (their path is ignored).

    Raises:
        SettingsError: an unknown option or an invalid value (the valid ones are named).
    """
    base = SequenceEntry(path="") if defaults is None else defaults
    path, sep, opts = str(text).rpartition("@")
    if not sep or "/" in opts:  # no options (an '@' inside the path itself is kept)
        path, opts = str(text), ""
    changes: dict = {"path": path}
    for token in filter(None, (t.strip() for t in opts.split(","))):
        key, eq, value = token.partition("=")
        key = key.strip().lower()
        if not eq:
            if key not in PROFILES:
                raise SettingsError(f"{text}: unknown option {token!r}; profiles: {', '.join(PROFILES)}; "
                                    f"options: {', '.join(sorted(k for k in _KEYS if '_' not in k))}=...")
            changes["profile"] = key
            continue
        if key not in _KEYS:
            raise SettingsError(f"{text}: unknown option {key!r}; valid: "
                                f"{', '.join(sorted(k for k in _KEYS if '_' not in k))}, or a profile")
        value = value.strip()
        if key == "frames":
            changes["frames"] = FrameSelection.parse(value)
        elif key in ("max-depth", "max_depth"):
            try:
                changes["max_depth"] = float(value)
            except ValueError:
                raise SettingsError(f"{text}: max-depth={value!r} is not a number") from None
        else:
            changes[key] = value.lower() if key in ("disparity", "crop", "pairing", "paper") else value
    return replace(base, **changes)


def entries_from_split(split_file, kitti_root, defaults: SequenceEntry | None = None) -> list[SequenceEntry]:
    """One entry per drive of a KITTI split file (camera 2), evaluating exactly the listed frames.

    Each drive is processed from its first frame to its last listed frame (earlier frames
    are the partners of the first listed ones).

    Raises:
        SequenceFormatError / InputError: see :mod:`vio_depth.io.kitti_split`.
        SettingsError: the split lists right-camera (``r`` / ``image_03``) frames.
    """
    base = SequenceEntry(path="") if defaults is None else defaults
    entries = []
    for drive in resolve_split(read_split_file(split_file), kitti_root, split_file):
        if drive.camera != 2:
            raise SettingsError(f"{split_file}:{drive.lines[0]}: camera {drive.camera} frames; vio-depth eval "
                                "evaluates the left colour camera (image_02) only")
        seq = open_sequence(drive.path)
        ev = tuple(frame_indices(seq, drive, split_file))
        entries.append(replace(base, path=str(drive.path), frames=FrameSelection(0, None, 1, ev),
                               name=Path(drive.drive).name))
    return entries


@dataclass(frozen=True)
class ResolvedEntry:
    """An entry with everything decided against its opened sequence (the task settings)."""

    entry: SequenceEntry
    format: str
    n_frames: int
    start: int
    stop: int
    evaluate: tuple[int, ...]
    mask: EvalMask
    pairing: str
    paper: str
    has_imu: bool

    def task_settings(self, disparity_cache: str | None, seed: int = 0) -> dict:
        """The JSON-able settings of this entry's tasks (part of their cache key)."""
        return {
            "format": self.format,
            "label": self.entry.label,
            "start": self.start,
            "stop": self.stop,
            "evaluate": list(self.evaluate),
            "mask": {"min_depth": self.mask.min_depth, "max_depth": self.mask.max_depth, "crop": self.mask.crop},
            "pairing": self.pairing,
            "paper": self.paper,
            "disparity": self.entry.disparity,
            "seed": int(seed),
            "disparity_cache": disparity_cache,
        }


def resolve_entry(entry: SequenceEntry) -> ResolvedEntry:
    """Open the sequence (metadata only) and decide frames, mask and presets.

    Raises:
        InputError: the sequence cannot be opened, lacks ground-truth depth, or the frames
            selection is outside it; SettingsError for contradictory options.
    """
    seq = open_sequence(entry.path, format=entry.format)
    if not seq.has_gt_depth:
        raise InputError(f"{entry.path}: no ground-truth depth; vio-depth eval scores against ground truth")
    if entry.disparity == "sequence" and seq.disparity is None:
        raise InputError(f"{entry.path}: the sequence carries no disparity; add @disparity=simulated "
                         "(SIMULATED from its ground truth) or run with --disparity simulated")
    prof = PROFILES[entry.profile]
    start, stop, ev = entry.frames.resolve(len(seq))
    crop = entry.crop if entry.crop is not None else (prof.kitti_crop if seq.format_name in KITTI_FORMATS
                                                      else "none")
    mask = EvalMask(max_depth=prof.max_depth if entry.max_depth is None else entry.max_depth, crop=crop)
    return ResolvedEntry(entry, seq.format_name, len(seq), start, stop, ev, mask,
                         entry.pairing or prof.pairing, entry.paper or prof.paper, seq.imu is not None)
