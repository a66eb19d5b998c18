"""Tests of vio_depth/experiments/tasks.py: executors agree, the cache resumes, errors name the task."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from vio_core.errors import MissingDependencyError, SettingsError, UnknownNameError
from vio_depth.experiments.tasks import ExecutorSettings, Task, TaskError, run_tasks, runner_name

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
STREET = ROOT / "sample_sequences" / "street"
ROOM = ROOT / "sample_sequences" / "room"


@pytest.fixture()
def runners(monkeypatch):
    """The runner module, importable by spawned workers (they inherit sys.path)."""
    monkeypatch.syspath_prepend(str(HERE))
    import eval_task_runners

    return eval_task_runners


def _tasks(log=None):
    extra = {} if log is None else {"log": str(log)}
    return [
        Task(str(STREET), "a", {"frames": [0, 5], "rel_sigma": 0.1, "seed": 1, **extra}),
        Task(str(ROOM), "a", {"frames": [3], "rel_sigma": 0.2, "seed": 2, **extra}),
        Task(str(STREET), "b", {"frames": [10], "rel_sigma": 0.05, "seed": 3, **extra}),
    ]


def test_task_is_normalised_and_hashable(monkeypatch):
    monkeypatch.chdir(ROOT)
    t = Task("sample_sequences/street", "sfm", {"b": 1, "a": (1, 2)})
    assert t.sequence == str(STREET) and t.settings == {"a": [1, 2], "b": 1}
    assert t == Task(str(STREET), "sfm", {"a": [1, 2], "b": 1}) and len({t, Task(str(STREET), "sfm", {"b": 1, "a": [1, 2]})}) == 1
    assert t.label == f"'sfm' on {STREET}"
    with pytest.raises(SettingsError, match="'sfm'"):
        Task(str(STREET), "sfm", {"x": float("nan")})
    with pytest.raises(SettingsError, match="not JSON-able"):
        Task(str(STREET), "sfm", {"x": {1, 2}})
    with pytest.raises(SettingsError):
        Task(str(STREET), "", {})


def test_cache_key_depends_on_every_input():
    t = Task(str(STREET), "sfm", {"a": 1})
    k = t.key("m:f", "0.1.0")
    assert k == Task(str(STREET), "sfm", {"a": 1}).key("m:f", "0.1.0")
    others = [Task(str(ROOM), "sfm", {"a": 1}).key("m:f", "0.1.0"), Task(str(STREET), "oracle", {"a": 1}).key("m:f", "0.1.0"),
              Task(str(STREET), "sfm", {"a": 2}).key("m:f", "0.1.0"), t.key("m:g", "0.1.0"), t.key("m:f", "0.2.0"),
              t.key("m:f", "0.1.0", salt="abc")]
    assert len(set(others + [k])) == 7


def test_executor_settings_are_checked():
    with pytest.raises(UnknownNameError, match="local"):
        ExecutorSettings(kind="dask")
    with pytest.raises(SettingsError):
        ExecutorSettings(workers=0)
    with pytest.raises(SettingsError, match="address"):
        ExecutorSettings(kind="local", address="auto")


def test_sequential_and_local_pool_give_identical_results(runners):
    tasks = _tasks() + [_tasks()[0]]  # a duplicate runs once and is returned twice
    seq = run_tasks(tasks, runners.frame_stats, executor=ExecutorSettings("sequential"), progress=False)
    pool = run_tasks(tasks, runners.frame_stats, executor=ExecutorSettings("local", workers=2), progress=False)
    assert seq == pool
    assert json.dumps(seq, sort_keys=True) == json.dumps(pool, sort_keys=True)
    assert seq[0] == seq[3] and seq[0] != seq[2]
    assert seq[0]["nan_becomes_none"] is None and seq[0]["numpy_int"] == 3
    assert set(seq[0]) >= {"frame_0", "frame_5"} and set(seq[1]) >= {"frame_3"}
    assert seq[1]["frame_3"]["mean_gt"] < 7.0 < seq[0]["frame_0"]["mean_gt"]  # room vs street


def test_cache_resumes_after_a_failure_without_rerunning_finished_tasks(runners, tmp_path):
    log, flag, cache = tmp_path / "log.txt", tmp_path / "flag", tmp_path / "cache"
    ok = Task(str(STREET), "ok", {"frames": [1], "log": str(log), "flag": str(tmp_path / "never")})
    bad = Task(str(STREET), "bad", {"frames": [2], "log": str(log), "flag": str(flag)})
    last = Task(str(ROOM), "last", {"frames": [0], "log": str(log), "flag": str(tmp_path / "never")})
    flag.touch()
    with pytest.raises(TaskError) as err:
        run_tasks([ok, bad, last], runners.fails_while_flag_exists, cache_dir=cache,
                  executor=ExecutorSettings("sequential"), progress=False)
    msg = str(err.value)
    assert msg == f"task 'bad' on {STREET}: /data/seq/poses.txt:3: expected 8 columns, got 7"
    assert "\n" not in msg and "Traceback" in err.value.details
    assert log.read_text().splitlines() == ["ok [1]"]  # stopped at the failing task
    assert len(list(cache.glob("*.json"))) == 1
    flag.unlink()
    results = run_tasks([ok, bad, last], runners.fails_while_flag_exists, cache_dir=cache,
                        executor=ExecutorSettings("local", workers=2), progress=False)
    assert sorted(log.read_text().splitlines()) == ["bad [2]", "last [0]", "ok [1]"]  # ok ran once
    assert [r["frames"] for r in results] == [130, 130, 120]
    entry = json.loads(next(iter(cache.glob("*.json"))).read_text())
    assert set(entry) >= {"task", "version", "result"}
    again = run_tasks([ok, bad, last], runners.fails_while_flag_exists, cache_dir=cache,
                      executor=ExecutorSettings("sequential"), progress=False)
    assert again == results and len(log.read_text().splitlines()) == 3  # all from the cache


def test_pool_errors_are_one_line_naming_the_task(runners, tmp_path):
    flag = tmp_path / "flag"
    flag.touch()
    bad = Task(str(ROOM), "bad", {"frames": [0], "flag": str(flag)})
    with pytest.raises(TaskError, match=r"^task 'bad' on .*room: /data/seq/poses.txt:3: expected 8 columns"):
        run_tasks([bad], runners.fails_while_flag_exists, executor=ExecutorSettings("local", workers=2),
                  progress=False)
    with pytest.raises(TaskError, match="'weird' on .*not JSON-able.*object"):
        run_tasks([Task(str(ROOM), "weird", {})], runners.not_jsonable, executor=ExecutorSettings("sequential"),
                  progress=False)


def test_ray_is_never_imported_unless_selected(tmp_path):
    code = (
        "import sys; sys.path.insert(0, %r)\n"
        "from vio_depth.experiments.tasks import run_tasks, Task, ExecutorSettings\n"
        "import eval_task_runners as r\n"
        "run_tasks([Task(%r, 'a', {'frames': [0]})], r.frame_stats, cache_dir=%r, "
        "executor=ExecutorSettings('local', workers=1), progress=False)\n"
        "assert 'ray' not in sys.modules, 'ray was imported'\n" % (str(HERE), str(STREET), str(tmp_path / "c"))
    )
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]


def test_missing_ray_gives_the_install_hint(runners, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # makes `import ray` fail
    with pytest.raises(MissingDependencyError, match="ray"):
        run_tasks(_tasks()[:1], runners.frame_stats, executor=ExecutorSettings("ray", workers=2), progress=False)


def test_local_ray_instance_with_two_workers_matches_sequential(runners, monkeypatch, tmp_path):
    pytest.importorskip("ray")
    # Ray workers are started by the raylet, which inherits this environment: let them import
    # this checkout and the runner module.
    monkeypatch.setenv("PYTHONPATH", f"{ROOT}:{HERE}")
    tasks = _tasks()
    seq = run_tasks(tasks, runners.frame_stats, executor=ExecutorSettings("sequential"), progress=False)
    ray_results = run_tasks(tasks, runners.frame_stats, cache_dir=tmp_path / "cache",
                            executor=ExecutorSettings("ray", workers=2), progress=False)
    assert ray_results == seq
    assert len(list((tmp_path / "cache").glob("*.json"))) == 3
    assert runner_name(runners.frame_stats) == "eval_task_runners:frame_stats"
