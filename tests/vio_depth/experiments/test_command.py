"""run_evaluation: identical numbers on every executor, resume from the cache, the files and the document."""

from pathlib import Path

import pytest

from vio_depth.experiments import ExecutorSettings, Task
from vio_depth.experiments import EvalRequest, compare_evaluations, parse_sequence_arg, parse_variants, run_evaluation
from vio_depth.experiments.command import interleave
from vio_depth.experiments.results import read_csv

ROOT = Path(__file__).resolve().parents[3]
STREET = ROOT / "sample_sequences" / "street"
ROOM = ROOT / "sample_sequences" / "room"


def _request(out, executor, **kw) -> EvalRequest:
    return EvalRequest(
        entries=[parse_sequence_arg(f"{STREET}@frames=0:6"), parse_sequence_arg(f"{ROOM}@indoor,frames=10:14")],
        variants=parse_variants("oracle,lidar:1,sfm,paper-reference"), out=Path(out), studies=["depth_noise"],
        study_frames=2, executor=executor, command=["vio-depth", "eval", "(test)"], progress=False, **kw)


@pytest.fixture(scope="module")
def sequential(tmp_path_factory):
    out = tmp_path_factory.mktemp("eval") / "sequential"
    return run_evaluation(_request(out, ExecutorSettings("sequential")))


def test_files_rows_and_document(sequential):
    out = sequential.out
    rows = read_csv(out / "results.csv")
    assert [(r["sequence"], r["variant"]) for r in rows] == [
        (s, v) for s in ("street", "room") for v in ("oracle", "lidar:1", "sfm", "paper-reference")]
    assert {r["disparity"] for r in rows} == {"simulated"}
    assert rows[0]["mask"] == "depth 0.001-80 m, no crop" and rows[4]["mask"] == "depth 0.001-10 m, no crop"
    assert len(read_csv(out / "frames.csv")) == 4 * (6 + 4)  # 4 variants x (6 street + 4 room) frames
    study = read_csv(out / "studies" / "depth_noise.csv")
    assert len(study) == 2 * 6 * 3  # 2 sequences x 6 noise levels x 3 fits
    assert sequential.tasks == 10 and sequential.tasks_cached == 0
    report = (out / "report.md").read_text()
    assert report.index("SIMULATED") < report.index("## Results per sequence")
    assert "| street | sfm |" in report and "study_depth_noise.png" in report
    for png in (out / "report").glob("*.png"):
        assert png.stat().st_size < 100_000, png


def test_local_pool_gives_identical_numbers_and_the_cache_resumes(sequential, tmp_path):
    local = run_evaluation(_request(tmp_path / "local", ExecutorSettings("local", workers=2)))
    cmp = compare_evaluations(sequential.out, local.out)
    assert cmp.identical and cmp.compared > 400, cmp.differences[:5]
    # an interrupted evaluation: one task's result is missing; a rerun computes only that one
    victim = sorted((local.out / "cache" / "tasks").glob("*.json"))[0]
    victim.unlink()
    again = run_evaluation(_request(tmp_path / "local", ExecutorSettings("sequential"),
                                    compare_with=sequential.out))
    assert again.tasks_cached == again.tasks - 1 and victim.is_file()
    assert compare_evaluations(sequential.out, again.out).identical
    assert "Identical numbers: yes" in (again.out / "report.md").read_text()


@pytest.mark.heavy  # ~25 s; test_tasks' Ray instance against the sequential run stays in the suite
def test_local_ray_instance_with_two_workers_gives_identical_numbers(sequential, tmp_path, monkeypatch):
    pytest.importorskip("ray")
    monkeypatch.setenv("PYTHONPATH", str(ROOT))  # Ray's workers import this checkout
    ray_run = run_evaluation(_request(tmp_path / "ray", ExecutorSettings("ray", workers=2)))
    cmp = compare_evaluations(sequential.out, ray_run.out)
    assert cmp.identical, cmp.differences[:5]


def test_tasks_are_handed_out_round_robin_over_sequences():
    tasks = [Task(str(STREET), v) for v in ("a", "b", "c")] + [Task(str(ROOM), v) for v in ("a", "b")]
    order = interleave(tasks, ["s", "s", "s", "r", "r"])
    assert [(Path(t.sequence).name, t.variant) for t in order] == [
        ("street", "a"), ("room", "a"), ("street", "b"), ("room", "b"), ("street", "c")]
