"""Run evaluation tasks sequentially, on a local process pool, or on a Ray cluster, with a disk cache.

A :class:`Task` is one unit of an evaluation: a sequence path, a variant name and a
JSON-able settings dict. A *runner* turns it into a JSON-able result dict::

    def runner(task: Task) -> dict          # a module-level function (workers import it)

:func:`run_tasks` runs a list of tasks with one runner and returns their results in task
order. The same results come back whichever executor ran them (every result goes through
``json.dumps``/``json.loads``, so floats, NaN -> None and numpy types are normalised the
same way), and every finished task is cached on disk at once, so an interrupted or failed
evaluation resumes where it stopped.

Executors (:class:`ExecutorSettings`):

* ``sequential`` -- in this process, one task after the other;
* ``local`` (the default) -- a process pool over all cores (``workers``); workers are
  *spawned* (not forked: OpenMP / OpenCV thread pools do not survive a fork) and get
  ``threads_per_worker`` BLAS/OpenMP threads each so that N workers do not oversubscribe N
  cores;
* ``ray`` -- Ray tasks (optional extra ``ray``; ``ray`` is imported only here): with
  ``address`` it joins a running cluster (``"auto"``, ``"ray://head:10001"``), else it
  starts a local instance with ``workers`` CPUs and shuts it down afterwards. See
  docs/evaluation_cluster.md for multi-node clusters.

Cache: ``cache_dir/<key>.json`` holds ``{"task", "version", "result"}``; ``key`` is the
SHA-256 of the task (absolute sequence path, variant, canonical settings JSON), the runner's
qualified name, the package version and an optional ``salt``. Results are written by the
driver only (workers need no access to the cache folder), atomically (temporary file +
rename). The cache does not notice changed input *data* or uncommitted code changes under
the same version: pass a new ``salt`` or delete the folder.

Errors: a task that raises stops the evaluation with one :class:`TaskError` line naming the
task (``task 'sfm' on /data/kitti/drive_0002: <message>``); tasks already running finish and
are cached first, tasks not yet started are cancelled. The full traceback is kept in
``TaskError.details``.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import math
import multiprocessing
import os
import sys
import tempfile
import traceback
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Callable, Iterator, Mapping

import numpy as np
from tqdm import tqdm

from vio_core.environment import environ
from vio_core.errors import MissingDependencyError, SettingsError, UnknownNameError, VioDepthError

log = logging.getLogger(__name__)

#: executor kinds of :class:`ExecutorSettings`
EXECUTORS = ("sequential", "local", "ray")
#: environment variables that bound the threads of numerical libraries in workers
THREAD_ENV_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS")


class TaskError(VioDepthError):
    """A task failed. The message is one line naming the task; ``details`` has the traceback."""

    def __init__(self, task: "Task", message: str, details: str = ""):
        self.task = task
        self.details = details
        super().__init__(f"task {task.label}: {' '.join(str(message).split())}")


def canonical_json(value) -> str:
    """Compact JSON with sorted keys (the form that is hashed).

    Raises:
        SettingsError: ``value`` is not JSON-able (sets, objects, NaN or infinity).
    """
    try:
        return json.dumps(value, sort_keys=True, separators=(",", ":"), allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise SettingsError(f"not JSON-able: {exc}") from None


@dataclass(frozen=True)
class Task:
    """One evaluation task.

    Attributes:
        sequence: path of the sequence; made absolute at construction (workers on other
            machines or in other folders see the same path).
        variant: variant name (the runner decides what it means).
        settings: JSON-able dict (checked at construction).
    """

    sequence: str
    variant: str
    settings: Mapping = field(default_factory=dict)

    def __post_init__(self):
        object.__setattr__(self, "sequence", str(Path(self.sequence).expanduser().resolve()))
        if not isinstance(self.variant, str) or not self.variant:
            raise SettingsError(f"task variant must be a non-empty string, got {self.variant!r}")
        if not isinstance(self.settings, Mapping):
            raise SettingsError(f"task {self.variant!r}: settings must be a dict, got {type(self.settings).__name__}")
        try:
            settings = json.loads(canonical_json(dict(self.settings)))
        except SettingsError as exc:
            raise SettingsError(f"task {self.variant!r} on {self.sequence}: settings {exc}") from None
        object.__setattr__(self, "settings", settings)

    @property
    def label(self) -> str:
        """``'variant' on /path/to/sequence`` (the name used in errors)."""
        return f"{self.variant!r} on {self.sequence}"

    def __hash__(self) -> int:
        return hash((self.sequence, self.variant, canonical_json(self.settings)))

    def to_json(self) -> dict:
        return {"sequence": self.sequence, "variant": self.variant, "settings": self.settings}

    def key(self, runner_name: str, version: str, salt: str = "") -> str:
        """SHA-256 hex digest of the task, the runner, the package version and ``salt``."""
        text = canonical_json({"task": self.to_json(), "runner": runner_name, "version": version, "salt": salt})
        return hashlib.sha256(text.encode()).hexdigest()


@dataclass(frozen=True)
class ExecutorSettings:
    """Where tasks run (see the module docstring).

    Attributes:
        kind: one of :data:`EXECUTORS`.
        workers: processes (``local``) or CPUs of a locally started Ray instance; None =
            every core (``os.cpu_count()``). Ignored by ``sequential`` and when joining a
            Ray cluster (its own resources decide).
        address: Ray only: address of a running cluster to join; None = start a local one.
        threads_per_worker: OpenMP/BLAS threads per worker process (:data:`THREAD_ENV_VARS`);
            None leaves the environment alone.
        start_method: multiprocessing start method of the ``local`` pool.
    """

    kind: str = "local"
    workers: int | None = None
    address: str | None = None
    threads_per_worker: int | None = 1
    start_method: str = "spawn"

    def __post_init__(self):
        if self.kind not in EXECUTORS:
            raise UnknownNameError("executor", self.kind, EXECUTORS)
        if self.workers is not None and self.workers < 1:
            raise SettingsError(f"workers must be >= 1, got {self.workers}")
        if self.threads_per_worker is not None and self.threads_per_worker < 1:
            raise SettingsError(f"threads_per_worker must be >= 1, got {self.threads_per_worker}")
        if self.address is not None and self.kind != "ray":
            raise SettingsError("--address is only used with the ray executor")
        if self.start_method not in multiprocessing.get_all_start_methods():
            raise UnknownNameError("start method", self.start_method, multiprocessing.get_all_start_methods())

    @property
    def n_workers(self) -> int:
        return self.workers or os.cpu_count() or 1


def package_version() -> str:
    """Installed version of vio-depth ("unknown" when it is not installed)."""
    try:
        return metadata.version("vio-depth")
    except metadata.PackageNotFoundError:
        return "unknown"


def runner_name(runner: Callable) -> str:
    """``module:qualname`` of a runner (part of the cache key)."""
    return f"{getattr(runner, '__module__', '?')}:{getattr(runner, '__qualname__', repr(runner))}"


def _jsonable(value):
    """Plain JSON types: numpy scalars/arrays converted, non-finite floats -> None, tuples -> lists."""
    if isinstance(value, dict):
        out = {}
        for k, v in value.items():
            if not isinstance(k, str):
                raise TypeError(f"dict key {k!r} is not a string")
            out[k] = _jsonable(v)
        return out
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if value is None or isinstance(value, str):
        return value
    raise TypeError(f"{type(value).__name__} value {value!r} is not JSON-able")


def execute_task(runner: Callable, task: Task) -> tuple[str, str, str]:
    """Run one task (in whatever process): ``("ok", result JSON, "")`` or ``("error", message, traceback)``.

    Never raises for a failing task: exceptions are turned into strings here, because not
    every exception survives pickling back to the driver.
    """
    try:
        result = runner(task)
        if not isinstance(result, dict):
            return "error", f"runner returned {type(result).__name__}, not a dict", ""
        try:
            return "ok", json.dumps(_jsonable(result), sort_keys=True, allow_nan=False), ""
        except (TypeError, ValueError) as exc:
            return "error", f"result is not JSON-able: {exc}", ""
    except Exception as exc:  # noqa: BLE001 -- reported to the driver as one line
        message = str(exc) if isinstance(exc, VioDepthError) else f"{type(exc).__name__}: {exc}"
        return "error", message, traceback.format_exc()


class TaskCache:
    """One JSON file per task under ``folder`` (see the module docstring); ``folder=None`` disables it."""

    def __init__(self, folder, runner: Callable, version: str, salt: str = ""):
        self.folder = None if folder is None else Path(folder)
        self.runner = runner_name(runner)
        self.version = version
        self.salt = salt
        if self.folder is not None:
            self.folder.mkdir(parents=True, exist_ok=True)

    def path(self, task: Task) -> Path | None:
        return None if self.folder is None else self.folder / f"{task.key(self.runner, self.version, self.salt)}.json"

    def load(self, task: Task) -> str | None:
        """The cached result JSON of ``task``, or None (absent, unreadable, or another task's)."""
        path = self.path(task)
        if path is None or not path.is_file():
            return None
        try:
            entry = json.loads(path.read_text())
        except (OSError, ValueError):
            return None
        if not isinstance(entry, dict) or entry.get("task") != task.to_json() or "result" not in entry:
            return None
        return json.dumps(entry["result"], sort_keys=True)

    def store(self, task: Task, result_json: str) -> None:
        path = self.path(task)
        if path is None:
            return
        entry = {"task": task.to_json(), "runner": self.runner, "version": self.version, "salt": self.salt,
                 "result": json.loads(result_json)}
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".partial")
        try:
            with os.fdopen(fd, "w") as fh:
                json.dump(entry, fh, sort_keys=True, indent=1)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise


@contextlib.contextmanager
def _thread_env(threads: int | None) -> Iterator[None]:
    """Set :data:`THREAD_ENV_VARS` while worker processes are started (they inherit them)."""
    if threads is None:
        yield
        return
    with environ({k: str(threads) for k in THREAD_ENV_VARS}):
        yield


def _progress_bar(total: int, initial: int, enabled: bool | None):
    enabled = sys.stderr.isatty() if enabled is None else enabled
    return tqdm(total=total, initial=initial, desc="tasks", unit="task", disable=not enabled, dynamic_ncols=True)


def run_tasks(tasks, runner: Callable, *, cache_dir=None, executor: ExecutorSettings | None = None,
              progress: bool | None = None, version: str | None = None, salt: str = "") -> list[dict]:
    """Run ``tasks`` with ``runner`` and return their result dicts in task order.

    Args:
        tasks: iterable of :class:`Task` (duplicates run once).
        runner: module-level function ``runner(task) -> dict`` (importable by workers).
        cache_dir: folder of the result cache; None = no cache.
        executor: :class:`ExecutorSettings` (default: local process pool over all cores).
        progress: one tqdm bar across all tasks (None = only when stderr is a terminal).
        version: part of the cache key; None = the installed vio-depth version.
        salt: extra cache-key text (e.g. a git commit) to invalidate old results.

    Raises:
        TaskError: a task raised or returned something that is not a JSON-able dict.
        MissingDependencyError: ``ray`` selected but not installed.
    """
    tasks = list(tasks)
    for t in tasks:
        if not isinstance(t, Task):
            raise SettingsError(f"run_tasks: expected Task objects, got {type(t).__name__}")
    executor = ExecutorSettings() if executor is None else executor
    cache = TaskCache(cache_dir, runner, package_version() if version is None else version, salt)
    unique = list(dict.fromkeys(tasks))
    done: dict[Task, str] = {}
    for t in unique:
        cached = cache.load(t)
        if cached is not None:
            done[t] = cached
    pending = [t for t in unique if t not in done]
    with _progress_bar(len(unique), len(done), progress) as bar:
        def finish(task: Task, outcome: tuple[str, str, str]) -> TaskError | None:
            status, payload, details = outcome
            if status != "ok":
                return TaskError(task, payload, details)
            cache.store(task, payload)
            done[task] = payload
            bar.update(1)
            return None

        if pending:
            if executor.kind == "sequential":
                _run_sequential(pending, runner, finish)
            elif executor.kind == "local":
                _run_local(pending, runner, executor, finish)
            else:
                _run_ray(pending, runner, executor, finish)
    return [json.loads(done[t]) for t in tasks]


def _run_sequential(pending, runner, finish) -> None:
    for task in pending:
        error = finish(task, execute_task(runner, task))
        if error is not None:
            raise error


def _run_local(pending, runner, executor: ExecutorSettings, finish) -> None:
    ctx = multiprocessing.get_context(executor.start_method)
    first_error: TaskError | None = None
    with _thread_env(executor.threads_per_worker):
        pool = ProcessPoolExecutor(max_workers=min(executor.n_workers, len(pending)), mp_context=ctx)
    try:
        futures = {pool.submit(execute_task, runner, t): t for t in pending}
        remaining = set(futures)
        while remaining:
            finished, remaining = wait(remaining, return_when=FIRST_COMPLETED)
            for fut in finished:
                task = futures[fut]
                if fut.cancelled():
                    continue
                try:
                    outcome = fut.result()
                except BrokenProcessPool as exc:
                    outcome = ("error", f"worker process died ({exc})", "")
                except Exception as exc:  # noqa: BLE001 -- e.g. the runner cannot be unpickled
                    outcome = ("error", f"{type(exc).__name__}: {exc}", traceback.format_exc())
                error = finish(task, outcome)
                if error is not None and first_error is None:
                    first_error = error
                    for other in remaining:
                        other.cancel()  # not started yet: never run; running ones finish and are cached
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
    if first_error is not None:
        raise first_error


#: the first Ray release with token authentication (``RAY_AUTH_MODE=token``), and the first
#: that asks for it by default for local instances
RAY_TOKEN_AUTH_VERSION = (2, 52)
RAY_TOKEN_AUTH_DEFAULT_VERSION = (2, 59)


def _version_tuple(text: str) -> tuple[int, ...]:
    parts = []
    for p in text.split(".")[:2]:
        digits = "".join(c for c in p if c.isdigit())
        parts.append(int(digits) if digits else 0)
    return tuple(parts)


def local_ray_problem(ray_version: str, auth_mode: str | None) -> str:
    """Why a private local Ray instance would be open to other machines ("" when it is not).

    Ray's services listen on every network interface and Ray deliberately never uses the
    loopback address for a node (``ray._private.services.resolve_ip_for_localhost``), so a
    local instance cannot be bound to localhost (measured with Ray 2.60: ``gcs_server`` and
    ``raylet`` on ``*:port``). What keeps other machines out is Ray's token authentication
    (``RAY_AUTH_MODE=token``): Ray 2.52-2.58 have it when the variable is set before the
    command starts (setting it later does not reach Ray), Ray >= 2.59 by default for local
    instances unless ``RAY_AUTH_MODE=disabled``; older Ray has none (docs/safety.md, "Security").
    """
    v = _version_tuple(ray_version)
    if v < RAY_TOKEN_AUTH_VERSION:
        return (f"Ray {ray_version} has no authentication and its services listen on every network interface: "
                "anyone who can reach this machine can run code in the evaluation's workers (use Ray >= 2.59, or "
                "--executor local on a machine others can reach)")
    token = auth_mode == "token" or (auth_mode is None and v >= RAY_TOKEN_AUTH_DEFAULT_VERSION)
    if not token:
        return (f"Ray {ray_version} runs without authentication (RAY_AUTH_MODE is {auth_mode or 'unset'}) and its "
                "services listen on every network interface: anyone who can reach this machine can run code in "
                "the evaluation's workers (set RAY_AUTH_MODE=token before the command)")
    return ""


def _run_ray(pending, runner, executor: ExecutorSettings, finish) -> None:
    try:
        import ray
    except ImportError:
        raise MissingDependencyError("ray", "ray", "the ray executor") from None
    env = {} if executor.threads_per_worker is None else {k: str(executor.threads_per_worker) for k in THREAD_ENV_VARS}
    if executor.address is None and not ray.is_initialized():
        problem = local_ray_problem(ray.__version__, os.environ.get("RAY_AUTH_MODE"))
        if problem:
            log.warning("%s", problem)
    _run_ray_tasks(ray, pending, runner, executor, finish, env)


def _run_ray_tasks(ray, pending, runner, executor: ExecutorSettings, finish, env: dict) -> None:
    started = False
    if not ray.is_initialized():
        kwargs = dict(runtime_env={"env_vars": env}, log_to_driver=False, logging_level=logging.WARNING)
        if executor.address is not None:
            ray.init(address=executor.address, **kwargs)
        else:  # a private instance without dashboard and job API (local_ray_environment: authentication)
            ray.init(num_cpus=executor.n_workers, include_dashboard=False, **kwargs)
        started = True
    first_error: TaskError | None = None
    try:
        remote = ray.remote(num_cpus=1, max_retries=0)(execute_task)
        refs = {remote.remote(runner, t): t for t in pending}
        while refs:
            ready, _ = ray.wait(list(refs), num_returns=1)
            for ref in ready:
                task = refs.pop(ref)
                try:
                    outcome = ray.get(ref)
                except Exception as exc:  # noqa: BLE001 -- worker crash, cancelled task, lost node
                    outcome = ("error", f"ray: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}",
                               str(exc))
                error = finish(task, outcome)
                if error is not None and first_error is None:
                    first_error = error
                    for other in list(refs):
                        ray.cancel(other)  # queued tasks never run; a running one may finish
    finally:
        if started:
            ray.shutdown()
    if first_error is not None:
        raise first_error
