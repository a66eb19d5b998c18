"""``vio-depth eval SEQ... --out DIR``: variants x sequences (and robustness studies) as cached tasks.

:func:`run_evaluation` is the API behind the command: it resolves the sequences
(:mod:`.plan`), makes one :class:`~vio_depth.experiments.tasks.Task` per sequence x variant and
per sequence x study, runs them with :func:`~vio_depth.experiments.tasks.run_tasks` (sequential, a
local process pool over all cores -- the default -- or Ray; one progress bar; each result
cached under ``DIR/cache`` so an interrupted evaluation resumes) and writes the files of
:mod:`.results`, then ``DIR/report.md`` (and, with ``markdown=``, that document too).
"""

from __future__ import annotations

import os
import platform
import time
from dataclasses import dataclass, field, replace
from datetime import datetime, timezone
from pathlib import Path

from vio_core.errors import SettingsError

from .._version import __version__
from ..evaluation import STUDIES
from .document import write_document
from .eval_folder import EvalFolder
from .plan import ResolvedEntry, SequenceEntry, resolve_entry
from .results import FRAME_COLUMNS, RESULT_COLUMNS, STUDY_COLUMNS, write_csv, write_json
from .runner import run_variant_task
from .studies import run_study_task
from .tasks import ExecutorSettings, Task, TaskCache, package_version, run_tasks
from .variants import Variant

STUDY_PREFIX = "study:"
#: frames a study processes before its first scored frame (partners, the filter's history)
STUDY_LEAD = 16


def run_eval_task(task: Task) -> dict:
    """The one runner of an evaluation: ``study:<name>`` tasks run a study, the others a variant."""
    if task.variant.startswith(STUDY_PREFIX):
        return run_study_task(task)
    return run_variant_task(task)


def parse_studies(specs) -> list[str]:
    """Study names from ``all``, ``none`` or a comma-separated list (order of :data:`STUDIES`)."""
    items = [specs] if isinstance(specs, str) else list(specs or [])
    names = [t.strip().lower() for s in items for t in str(s).split(",") if t.strip()]
    if names in ([], ["none"]):
        return []
    if "all" in names:
        return list(STUDIES)
    unknown = [n for n in names if n not in STUDIES]
    if unknown:
        raise SettingsError(f"unknown study {', '.join(unknown)}; valid: all, none, {', '.join(STUDIES)}")
    return [n for n in STUDIES if n in names]


@dataclass
class EvalRequest:
    """Everything ``vio-depth eval`` was asked to do.

    Attributes:
        entries: the sequences (:class:`~.plan.SequenceEntry`).
        variants: the variants, each run on every sequence.
        out: the evaluation folder.
        studies: robustness study names (:func:`parse_studies`).
        study_frames: studies score this many evaluated frames of each sequence
            (:func:`study_frames`: a block in the middle, processed from :data:`STUDY_LEAD`
            frames before it).
        executor: where the tasks run.
        seed: seed of every random choice (RANSAC, SIMULATED disparity, perturbations).
        markdown: also write this Markdown document (figures beside it), or None.
        compare_with: an earlier evaluation folder to compare with in the documents, or None.
        command: the command line, recorded in eval.json.
        progress: one progress bar (None = when stderr is a terminal).
    """

    entries: list[SequenceEntry]
    variants: list[Variant]
    out: Path
    studies: list[str] = field(default_factory=list)
    study_frames: int = 20
    executor: ExecutorSettings = field(default_factory=ExecutorSettings)
    seed: int = 0
    markdown: Path | None = None
    compare_with: Path | None = None
    command: list[str] = field(default_factory=list)
    progress: bool | None = None


@dataclass
class EvalOutcome:
    """What :func:`run_evaluation` wrote and measured."""

    out: Path
    rows: list[dict]
    wall_seconds: float
    tasks: int
    tasks_cached: int
    documents: list[Path]


def _unique_labels(resolved: list[ResolvedEntry]) -> list[ResolvedEntry]:
    seen: dict[str, int] = {}
    out = []
    for r in resolved:
        label = r.entry.label
        seen[label] = seen.get(label, 0) + 1
        if seen[label] > 1:
            r = replace(r, entry=replace(r.entry, name=f"{label}#{seen[label]}"))
        out.append(r)
    return out


def study_frames(evaluate, n: int) -> list[int]:
    """The ``n`` evaluated frames a study scores: a block in the middle of ``evaluate`` (the first
    frames of a sequence have the fewest partners)."""
    ev = list(evaluate)
    first = max(0, (len(ev) - n) // 2)
    return ev[first:first + n]


def _study_settings(r: ResolvedEntry, base: dict, n: int) -> dict:
    ev = study_frames(r.evaluate, n)
    return {**base, "evaluate": ev, "start": max(r.start, ev[0] - STUDY_LEAD), "stop": ev[-1] + 1}


def build_tasks(resolved: list[ResolvedEntry], request: EvalRequest,
                disparity_cache: str) -> list[tuple[Task, ResolvedEntry]]:
    """One task per sequence x variant, then per sequence x study, each with its entry."""
    tasks = []
    for r in resolved:
        base = r.task_settings(disparity_cache, request.seed)
        tasks += [(Task(r.entry.path, v.name, base), r) for v in request.variants]
    for name in request.studies:
        for r in resolved:
            base = r.task_settings(disparity_cache, request.seed)
            tasks.append((Task(r.entry.path, STUDY_PREFIX + name, _study_settings(r, base, request.study_frames)), r))
    return tasks


def interleave(tasks: list[Task], groups: list[str]) -> list[Task]:
    """``tasks`` reordered round-robin over their ``groups`` (sequences), keeping each group's order:
    workers that start together then work on different sequences (and disparity maps)."""
    queues: dict[str, list[Task]] = {}
    for t, g in zip(tasks, groups, strict=True):
        queues.setdefault(g, []).append(t)
    out = []
    while any(queues.values()):
        for q in queues.values():
            if q:
                out.append(q.pop(0))
    return out


def _meta(request: EvalRequest, resolved: list[ResolvedEntry], kinds: dict, wall: float, n_tasks: int,
          n_cached: int, started: str) -> dict:
    ex = request.executor
    return {
        "vio_depth_version": __version__,
        "command": request.command,
        "started": started,
        "wall_seconds": round(wall, 1),
        "executor": {"kind": ex.kind, "workers": ex.n_workers if ex.address is None else None, "address": ex.address},
        "cpu_count": os.cpu_count(),
        "platform": f"{platform.system()} {platform.machine()}, Python {platform.python_version()}",
        "seed": request.seed,
        "sequences": [{
            "label": r.entry.label, "path": r.entry.path, "format": r.format, "profile": r.entry.profile,
            "disparity": r.entry.disparity, "disparity_kind": kinds.get(r.entry.label, ""),
            "frames": {"start": r.start, "stop": r.stop, "evaluated": len(r.evaluate),
                       "selection": r.entry.frames.describe()},
            "mask": r.mask.describe(), "pairing": r.pairing, "paper": r.paper} for r in resolved],
        "variants": [v.name for v in request.variants],
        "studies": request.studies,
        "study_frames": request.study_frames,
        "tasks": n_tasks,
        "tasks_cached": n_cached,
    }


def run_evaluation(request: EvalRequest) -> EvalOutcome:
    """Run the evaluation of ``request`` and write its folder (see the module docstring).

    Raises:
        InputError / SettingsError: a sequence cannot be evaluated or an option is invalid
            (before any task runs); OutputFolderError: ``request.out`` cannot be used
            (:mod:`.eval_folder`, before anything is written); TaskError: a task failed
            (finished tasks stay cached).
    """
    if not request.entries:
        raise SettingsError("no sequence to evaluate (give SEQ... or --kitti-split FILE --kitti-root DIR)")
    if request.study_frames < 1:
        raise SettingsError(f"--study-frames must be >= 1, got {request.study_frames}")
    folder = EvalFolder(request.out, [e.path for e in request.entries] + [request.compare_with],
                        markdown=request.markdown)
    resolved = _unique_labels([resolve_entry(e) for e in request.entries])
    folder.claim()  # the same refusals as `vio-depth run --out`, before anything is written
    try:
        return _evaluate(request, resolved, folder.out)
    finally:
        folder.release()


def _evaluate(request: EvalRequest, resolved: list[ResolvedEntry], out: Path) -> EvalOutcome:
    """The tasks of ``request`` run and their results written into ``out`` (claimed)."""
    cache = out / "cache"
    pairs = build_tasks(resolved, request, str((cache / "disparity").resolve()))
    tasks = [t for t, _ in pairs]
    started = datetime.now(timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    version = package_version()
    task_cache = TaskCache(cache / "tasks", run_eval_task, version)
    n_cached = sum(task_cache.load(t) is not None for t in dict.fromkeys(tasks))
    order = interleave(tasks, [r.entry.label for _, r in pairs])
    t0 = time.perf_counter()
    done = run_tasks(order, run_eval_task, cache_dir=cache / "tasks", executor=request.executor,
                     progress=request.progress, version=version)
    wall = time.perf_counter() - t0
    by_task = dict(zip(order, done, strict=True))
    results = [by_task[t] for t in tasks]
    rows, frames, studies, kinds = [], [], {}, {}
    for (task, r), res in zip(pairs, results, strict=True):
        label = r.entry.label
        if task.variant.startswith(STUDY_PREFIX):
            for row in res["rows"]:
                studies.setdefault(res["study"], []).append(
                    {"sequence": label, "study": res["study"], "parameter": res["parameter"], "unit": res["unit"],
                     **row})
            continue
        kinds[label] = res["disparity_kind"]
        rows.append({"sequence": label, "variant": res["variant"], "disparity": res["disparity_kind"],
                     "mask": r.mask.describe(), "evaluated_frames": len(r.evaluate), **res["row"]})
        frames += [{"sequence": label, "variant": res["variant"], **f} for f in res["frames"]]
    write_csv(out / "results.csv", RESULT_COLUMNS, rows)
    write_csv(out / "frames.csv", FRAME_COLUMNS, frames)
    for name in request.studies:
        write_csv(out / "studies" / f"{name}.csv", STUDY_COLUMNS + ("unit",), studies.get(name, []))
    write_json(out / "eval.json", _meta(request, resolved, kinds, wall, len(tasks), n_cached, started))
    docs = [write_document(out, out / "report.md", compare_with=request.compare_with)]
    if request.markdown is not None:
        docs.append(write_document(out, request.markdown, compare_with=request.compare_with))
    return EvalOutcome(out, rows, wall, len(tasks), n_cached, docs)


def format_results(rows: list[dict]) -> str:
    """The printed table: one line per sequence x variant."""
    head = f"{'sequence':18} {'variant':22} {'delta1':>7} {'AbsRel':>7} {'RMSE':>7} {'coverage':>8} {'pts/fr':>7}"
    lines = [head]
    for r in rows:
        def f(k, spec):
            v = r.get(k)
            return format("-", ">" + spec.split(".")[0]) if v is None else format(v, spec)
        lines.append(f"{r['sequence'][:18]:18} {r['variant'][:22]:22} {f('delta1', '7.4f')} {f('abs_rel', '7.4f')} "
                     f"{f('rmse', '7.3f')} {f('coverage', '8.3f')} {f('points_per_frame', '7.0f')}")
    return "\n".join(lines)
