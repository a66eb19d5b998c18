"""Resuming an interrupted run: what may be continued, and the checks that keep it exact.

``vio-depth run ... --resume`` continues a run that failed, was interrupted or was killed
(``SIGKILL`` included), from its staging folder (:mod:`vio_depth.run.folder`):

1. The journal's run header must match the new run's: the package version, the record
   schema, the sequence (folder, format, name, frame count), the disparity kind and every
   setting (``vio-depth config --dump`` form). Any difference refuses the resume, naming
   the first differing key; the command line itself may differ.
2. The frames the journal records as complete (``k`` of them) keep their files. The
   per-frame files of later frames, the depth of recorded frames without depth (left by an
   interrupted backward pass) and the outputs written at the end of a run are removed.
3. Frames ``0 .. k-1`` are **replayed** through a fresh pipeline without writing: the
   keyframe buffer, the rescaler's filter and fallback state and the IMU pose source are
   stateful, and replaying is the one way to rebuild them exactly. Each replayed record
   must equal the journaled one (every field except ``seconds`` and ``timings``), else the
   resume is refused (the inputs changed, or the computation is not reproducible here).
4. Frames ``k ..`` are processed and written as in an uninterrupted run, then the backward
   pass and the run-end outputs. The result is identical to an uninterrupted run except
   for timings and the recorded command line.

Replaying costs the pipeline time of the first ``k`` frames (not their writing or
evaluation output); it is what makes the result exact.

With ``--resume`` and no interrupted run: an ``--out`` holding the same finished run is
left as it is ("nothing to resume"); a different finished run is refused; otherwise the
run starts from frame 0.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

from .folder import OutputFolder, OutputFolderError, OutputMode
from .record import read_frames_jsonl

#: header keys that must match for a resume (the command line may differ)
COMPARED_HEADER_KEYS = ("schema_version", "vio_depth_version", "sequence", "disparity_kind", "settings")
#: frame-record keys that legitimately differ between a run and its replay
VOLATILE_RECORD_KEYS = ("seconds", "timings")


class ResumeError(OutputFolderError):
    """An interrupted run cannot be continued (the message says why and what to do)."""


def _canon(value: Any) -> str:
    return json.dumps(value, sort_keys=True)


def first_difference(stored: Any, current: Any, where: str = "") -> str | None:
    """The first key path where two JSON values differ, as ``"path: stored X, now Y"``; None if equal."""
    if isinstance(stored, dict) and isinstance(current, dict):
        for key in sorted(set(stored) | set(current)):
            sub = f"{where}.{key}" if where else str(key)
            if key not in stored or key not in current:
                return f"{sub}: {'missing' if key not in stored else _short(stored[key])} before, " \
                       f"{'missing' if key not in current else _short(current[key])} now"
            diff = first_difference(stored[key], current[key], sub)
            if diff:
                return diff
        return None
    if _canon(stored) != _canon(current):
        return f"{where or 'value'}: {_short(stored)} before, {_short(current)} now"
    return None


def _short(value: Any) -> str:
    text = _canon(value)
    return text if len(text) <= 60 else text[:57] + "..."


def header_difference(stored: dict, current: dict) -> str | None:
    """Why a run with header ``current`` cannot continue one with header ``stored`` (None: it can)."""
    current = json.loads(json.dumps(current))
    return first_difference({k: stored.get(k) for k in COMPARED_HEADER_KEYS},
                            {k: current.get(k) for k in COMPARED_HEADER_KEYS})


def record_difference(stored: dict, replayed: dict) -> str | None:
    """Why a replayed frame record differs from the journaled one (None: equal but for timings)."""
    a = {k: v for k, v in stored.items() if k not in VOLATILE_RECORD_KEYS}
    b = {k: v for k, v in json.loads(json.dumps(replayed)).items() if k not in VOLATILE_RECORD_KEYS}
    return first_difference(a, b)


@dataclass
class ResumePlan:
    """Where a run starts.

    Attributes:
        records: the journaled frame records of frames ``0 .. k-1`` (replayed, not rewritten).
        complete: ``--out`` already holds this finished run: nothing to do.
    """

    records: list[dict] = field(default_factory=list)
    complete: bool = False

    @property
    def start(self) -> int:
        return len(self.records)


def check_replayed(folder: OutputFolder, plan: ResumePlan, i: int, stem: str, record: dict) -> None:
    """Check frame ``i``'s (``stem``) record from the replay against the journaled one (step 3).

    Raises:
        ResumeError: they differ (names the first differing field).
    """
    diff = record_difference(plan.records[i], record)
    if diff:
        raise ResumeError(f"{folder.out}: cannot resume, replaying frame {i} ({stem}) gave another "
                          f"result than the interrupted run ({diff}); give --overwrite to start over")


def plan_run(folder: OutputFolder, header: dict, stems: list[str]) -> ResumePlan:
    """Claim the staging folder for a run with ``header`` over frames named ``stems``.

    Raises:
        OutputFolderError: ``--out`` cannot be used in this mode.
        ResumeError: an interrupted run or a finished one differs from this run.
    """
    if folder.mode == OutputMode.RESUME:
        if folder.interrupted():
            folder.claim_interrupted()
            try:
                stored, records = folder.read_journal()
                if stored is not None:
                    diff = header_difference(stored, header)
                    if diff:
                        raise ResumeError(f"{folder.out}: cannot resume, the interrupted run differs ({diff}); "
                                          "give --overwrite to start over")
                records = records[: len(stems)]
                k = len(records)
                no_depth = [r["stem"] for r in records if r.get("alpha") is None]
                folder.prune(stems[k:], depth_only=no_depth)
                folder.start_journal(header, records)
            except BaseException:
                folder.release()
                raise
            return ResumePlan(records)
        if folder.existing_run():
            stored, _ = read_frames_jsonl(folder.out / "frames.jsonl")
            diff = "no run header" if stored is None else header_difference(stored, header)
            if diff:
                raise ResumeError(f"{folder.out}: holds a different finished run ({diff}); give --overwrite to "
                                  "replace it")
            return ResumePlan(complete=True)
    folder.claim_new()
    try:
        folder.start_journal(header)
    except BaseException:
        folder.release()
        raise
    return ResumePlan()
