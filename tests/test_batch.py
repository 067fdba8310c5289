"""``slamcli batch`` end to end: statuses, records, exit codes, resume, baselines, timeouts,
retries, and the same bytes on a local pool and on a Dask cluster."""

from __future__ import annotations

import json
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from slamcli.batch.job import JobResult, RunJob, run_isolated
from slamcli.batch.metrics import known_metric
from slamcli.batch.runner import plan_batch, run_batch
from slamcli.cli.app import app

ROOT = Path(__file__).resolve().parents[1]
ROOM = ROOT / "sample_data" / "rgbd_room"
runner = CliRunner()


@pytest.fixture(scope="module")
def data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A folder with a short landmark world, a link to the sample RGB-D room, and a copy of
    the room with one colour image missing (a run that loses data)."""
    from slamcli.synth.landmarks import generate_landmark_world

    root = tmp_path_factory.mktemp("batchdata")
    generate_landmark_world(root / "world", duration_s=30.0)
    (root / "room").symlink_to(ROOM)
    holed = root / "holed"
    shutil.copytree(ROOM, holed)
    first = sorted((holed / "rgb").iterdir())[3]
    first.unlink()
    return root


def _manifest(folder: Path, text: str) -> Path:
    path = folder / "batch.toml"
    path.write_text(text)
    return path


MIXED = """
[defaults]
fail_if = ["ate.rmse > 0.5"]

[[job]]
name = "ekf-world"
input = "world"
pipeline = "ekf"
fail_if = ["ate.rmse > 0.2", "landmarks.rmse_m > 0.2"]

[[job]]
name = "visual-strict"
input = "room"
pipeline = "visual"
max_frames = 10
fail_if = ["ate.rmse > 0.000001"]

[[job]]
name = "visual-holed"
input = "holed"
pipeline = "visual"
max_frames = 10

[[job]]
name = "ekf-on-images"
input = "room"
pipeline = "ekf"
"""


def _batch(args: list[str]) -> Any:
    return runner.invoke(app, ["batch", *args])


def test_a_mixed_batch_reports_every_job_and_exits_1(data: Path, tmp_path: Path) -> None:
    manifest = _manifest(data, MIXED)
    out = tmp_path / "ci"
    res = _batch([str(manifest), "--out", str(out), "--jobs", "2"])
    assert res.exit_code == 1, res.output  # one job could not run
    record = json.loads((out / "batch.json").read_text())
    status = {j["name"]: j["status"] for j in record["jobs"]}
    assert status == {
        "ekf-world": "passed",
        "visual-strict": "gate_failed",
        "visual-holed": "data_lost",
        "ekf-on-images": "error",
    }
    assert [j["name"] for j in record["jobs"]] == list(status)  # manifest order
    assert record["exit_code"] == 1 and record["counts"]["error"] == 1
    strict = next(j for j in record["jobs"] if j["name"] == "visual-strict")
    gate = strict["gates"][0]
    assert gate["failed"] and gate["value"] > 0.000001 and gate["limit"] == 0.000001
    assert strict["metrics"]["ate.rmse"] == gate["value"]
    broken = next(j for j in record["jobs"] if j["name"] == "ekf-on-images")
    assert "room" in broken["error"] and broken["exit_code"] == 1
    # Run folders are exactly those of the jobs that ran; the failed one left nothing.
    assert sorted(p.name for p in out.iterdir()) == sorted(
        ["batch.json", "junit.xml", "report.html", "ekf-world", "visual-strict", "visual-holed"]
    )
    assert (out / "visual-strict" / "trajectory.tum").exists()

    suite = ET.parse(out / "junit.xml").getroot().find("testsuite")
    assert suite is not None
    assert (suite.get("tests"), suite.get("failures"), suite.get("errors")) == ("4", "2", "1")
    cases = {c.get("name"): c for c in suite.iter("testcase")}
    assert cases["visual-strict"].find("failure") is not None
    assert cases["visual-holed"].find("failure") is not None
    assert cases["ekf-on-images"].find("error") is not None
    assert (
        cases["ekf-world"].find("failure") is None and cases["ekf-world"].get("classname") == "ekf"
    )

    html = (out / "report.html").read_text()
    for name in status:
        assert name in html
    assert "data:image/png;base64," in html  # the runs' report.png, embedded
    assert "http://" not in html and "https://" not in html

    # The console names every job with its status.
    for name, state in status.items():
        assert name in res.output and state in res.output


def test_gate_failures_and_lost_data_alone_exit_3(data: Path, tmp_path: Path) -> None:
    manifest = _manifest(
        tmp_path,
        f"""
[[job]]
name = "strict"
input = "{data / "room"}"
pipeline = "visual"
max_frames = 8
fail_if = ["frames.processed < 9"]
""",
    )
    res = _batch([str(manifest), "--out", str(tmp_path / "out")])
    assert res.exit_code == 3, res.output


def test_manifest_errors_stop_everything_before_it_runs(data: Path, tmp_path: Path) -> None:
    cases = {
        'fail_if = ["fram.lost > 0"]': ('unknown metric "fram.lost"', 5),
        "set = { max_featurez = 10 }": ("max_featurez", 5),
        "source = { robut = 2 }": ("robut", 5),
        'fail_if = ["ate.rmse > 1.1 * baseline"]': ("baseline", 5),
    }
    for extra, (words, line) in cases.items():
        manifest = _manifest(
            tmp_path,
            f'[[job]]\nname = "a"\ninput = "{data / "room"}"\npipeline = "visual"\n{extra}\n',
        )
        out = tmp_path / "never"
        res = _batch([str(manifest), "--out", str(out)])
        assert res.exit_code == 1, (extra, res.output)
        assert words in res.output, (extra, res.output)
        assert f"{manifest}:{line}" in res.output or f"batch.toml:{line}" in res.output, (
            extra,
            res.output,
        )
        assert not out.exists()


def _job_files(out: Path) -> dict[str, bytes]:
    return {p.parent.name: p.read_bytes() for p in sorted(out.glob("*/trajectory.tum"))}


FAST = """
[[job]]
name = "ekf-world"
input = "world"
pipeline = "ekf"
fail_if = ["ate.rmse > 1.0"]

[[job]]
name = "visual-room"
input = "room"
pipeline = "visual"
max_frames = 10
fail_if = ["ate.rmse > 1.10 * baseline", "ms_per_frame > 100 * baseline"]
"""


def test_resume_skips_complete_runs_of_the_same_job_only(data: Path, tmp_path: Path) -> None:
    manifest = _manifest(
        data,
        FAST.replace(', "ms_per_frame > 100 * baseline"', "").replace("1.10 * baseline", "0.5"),
    )
    out = tmp_path / "ci"
    plan = plan_batch(manifest, out)
    first = run_batch(plan, jobs=2)
    assert [r.status for r in first.results] == ["passed", "passed"]
    stamps = {n: (out / n / "run.json").stat().st_mtime_ns for n in ("ekf-world", "visual-room")}

    again = run_batch(plan_batch(manifest, out), jobs=2, resume=True)
    assert [r.resumed for r in again.results] == [True, True]
    assert [r.metrics["ate.rmse"] for r in again.results] == [
        r.metrics["ate.rmse"] for r in first.results
    ]
    assert {n: (out / n / "run.json").stat().st_mtime_ns for n in stamps} == stamps

    # A partial folder is never done; another setting is another job.
    (out / "ekf-world" / "landmarks.csv").unlink()
    changed = manifest.read_text().replace("max_frames = 10", "max_frames = 9")
    manifest.write_text(changed)
    third = run_batch(plan_batch(manifest, out), jobs=2, resume=True)
    assert [r.resumed for r in third.results] == [False, False]
    assert (out / "ekf-world" / "landmarks.csv").exists()
    assert third.results[1].counts["frames_processed"] == 9


def test_a_baseline_adds_changes_and_feeds_gates(data: Path, tmp_path: Path) -> None:
    manifest = _manifest(
        tmp_path,
        FAST.replace('"world"', f'"{data / "world"}"').replace('"room"', f'"{data / "room"}"'),
    )
    base_manifest = tmp_path / "base.toml"
    base_manifest.write_text(manifest.read_text().split('fail_if = ["ate.rmse > 1.10')[0])
    base = tmp_path / "base"
    assert run_batch(plan_batch(base_manifest, base), jobs=2).exit_code == 0
    res = _batch([str(manifest), "--out", str(tmp_path / "new"), "--baseline", str(base)])
    assert res.exit_code == 0, res.output
    record = json.loads((tmp_path / "new" / "batch.json").read_text())
    visual = record["jobs"][1]
    before, now = visual["changes"]["ate.rmse"]
    assert before == now  # the same job, the same numbers
    gates = {g["gate"]: g for g in visual["gates"]}
    assert gates["ate.rmse > 1.10 * baseline"]["limit"] == pytest.approx(1.10 * before)
    assert not any(g["failed"] for g in visual["gates"])
    assert record["baseline"] == str(base.resolve())
    assert "(+0.0%)" in res.output


def test_timeouts_stop_a_job_and_its_helpers_and_leave_nothing(data: Path, tmp_path: Path) -> None:
    job = RunJob(
        pipeline="visual",
        input=data / "room",
        out=tmp_path / "slow",
        name="slow",
        timeout_s=1.0,
    )
    result = run_isolated(job, retries=3)
    assert result.status == "error" and "timed out after 1 s" in result.error
    assert result.attempts == 1  # a timeout is not retried
    assert list(tmp_path.iterdir()) == []


def test_a_job_whose_process_dies_is_tried_again(
    data: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import slamcli.batch.job as jobmod

    real = jobmod._child
    calls: list[int] = []

    def dies_once(job: RunJob) -> tuple[JobResult | None, str]:
        calls.append(1)
        if len(calls) == 1:
            return None, "the job's process stopped (killed by signal 9)"
        return real(job)

    monkeypatch.setattr(jobmod, "_child", dies_once)
    job = RunJob(pipeline="ekf", input=data / "world", out=tmp_path / "w", name="w")
    result = run_isolated(job, retries=1)
    assert result.status == "passed" and result.attempts == 2
    calls.clear()
    monkeypatch.setattr(jobmod, "_child", lambda job: (None, "killed by signal 11"))
    gone = run_isolated(job, retries=2)
    assert gone.status == "error" and gone.attempts == 3 and "signal 11" in gone.error


def test_an_unreachable_scheduler_is_a_one_line_error(
    data: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    distributed = pytest.importorskip("distributed")
    real_client = distributed.Client
    connects: list[str] = []

    def client(address: str, *args: Any, timeout: Any = None, **kwargs: Any) -> Any:
        # A refused connection is retried until the connect timeout (10 s in the command);
        # one second ends the same way, through the same error boundary.
        connects.append(address)
        return real_client(address, *args, timeout="1s", **kwargs)

    monkeypatch.setattr(distributed, "Client", client)
    manifest = _manifest(
        tmp_path, f'[[job]]\nname = "a"\ninput = "{data / "world"}"\npipeline = "ekf"\n'
    )
    res = _batch([str(manifest), "--out", str(tmp_path / "o"), "--scheduler", "tcp://127.0.0.1:9"])
    assert res.exit_code == 1, res.output
    assert "cannot reach the Dask scheduler" in res.output and "Traceback" not in res.output
    assert connects == ["tcp://127.0.0.1:9"]


@pytest.mark.parametrize("pipeline", ["dense", "visual", "odometry", "ekf"])
def test_every_figure_a_run_writes_is_a_known_gate_metric(
    pipeline: str, data: Path, tmp_path: Path
) -> None:
    from slamcli.batch.gates import flatten_metrics
    from slamcli.run import run_pipeline

    source = data / ("world" if pipeline == "ekf" else "room")
    outcome = run_pipeline(
        source, pipeline, tmp_path / "r", max_frames=None if pipeline == "ekf" else 6
    )
    names = flatten_metrics(json.loads((outcome.run_dir / "run.json").read_text()))
    assert "ate.rmse" in names
    # Peak memory, as the operating system counts it (this process has loaded numpy at least).
    assert names["memory.peak_rss_mb"] > 50
    # Every run counts the reasons it doubts its result; these short clean runs have none.
    assert names["doubts"] == 0
    unknown = [n for n in names if not known_metric(pipeline, n)]
    assert unknown == []
    for typo in ("ate.rmsee", "fram.lost", "frames.lots", "ms_per_frame.a.b"):
        assert not known_metric(pipeline, typo)


def test_run_fail_if_exits_3_with_the_folder_complete(tmp_path: Path) -> None:
    out = tmp_path / "run"
    res = runner.invoke(
        app,
        [
            "run",
            "visual",
            str(ROOM),
            "--out",
            str(out),
            "--max-frames",
            "8",
            "--fail-if",
            "frames.processed < 9",
            "--fail-if",
            "frames.lost > 0",
        ],
    )
    assert res.exit_code == 3, res.output
    assert "1 of 2 gate(s) failed" in res.output
    assert (out / "run.json").exists()
    bad = runner.invoke(
        app,
        ["run", "visual", str(ROOM), "--out", str(tmp_path / "no"), "--fail-if", "fram.lost > 0"],
    )
    assert bad.exit_code == 1 and "fram.lost" in bad.output
    assert not (tmp_path / "no").exists()


# --- a manifest over the shared data, of every kind of job --------------------------------------

# Each job reads a stretch of its log: the tests here judge the batch (statuses, exit code,
# junit.xml, the same bytes on Dask), and the pipelines' accuracy over whole logs is the
# pipelines' tests' to judge.
SHARED_MANIFEST = """
[defaults]
fail_if = ["ate.rmse > 0.1"]

[[job]]
name = "dense-rpy"
input = "{tum}"
pipeline = "dense"
max_frames = 20
fail_if = ["ate.rmse > 0.03", "frames.lost > 0"]

[[job]]
name = "visual-rpy"
input = "{tum}"
pipeline = "visual"
max_frames = 40
fail_if = ["ate.rmse > 0.03", "frames.lost > 0"]

[[job]]
name = "visual-rpy-impossible"
input = "{tum}"
pipeline = "visual"
max_frames = 30
fail_if = ["ate.rmse > 0.0001"]

[[job]]
name = "missing-log"
input = "{tum}_not_there"
pipeline = "visual"
""" + "".join(
    f"""
[[job]]
name = "ekf-mrclam-{n}"
input = "{{mrclam}}"
pipeline = "ekf"
source = {{ robot = {n} }}
max_frames = 8000
fail_if = ["ate.rmse > 0.5", "landmarks.rmse_m > 0.5"]
"""
    for n in range(1, 6)
)


@pytest.fixture(scope="module")
def shared_batch(shared_run: Any, shared_artefact: Any) -> dict[str, Any]:
    """The manifest run with --jobs 2 through the CLI, once per test session (the tests that
    read it may run in different test processes)."""
    from conftest import shared_path

    tum = shared_path("tum", "rgbd_dataset_freiburg1_rpy_excerpt")
    mrclam = shared_path("landmarks", "MRCLAM_Dataset6")
    text = SHARED_MANIFEST.replace("{tum}", str(tum)).replace("{mrclam}", str(mrclam))
    folder = shared_artefact("batch-shared-manifest", lambda f: (f / "ci.toml").write_text(text))
    manifest = folder / "ci.toml"
    assert manifest.read_text() == text
    local = shared_run("batch", manifest, "--jobs", "2")
    assert local.exception is None, local.output
    return {"manifest": manifest, "local": local}


def test_shared_manifest_statuses_exit_code_and_junit(shared_batch: dict[str, Any]) -> None:
    from junitparser import Error, Failure, JUnitXml

    res = shared_batch["local"]
    assert res.exit_code == 1, res.output  # the missing log could not run
    out = res.out
    record = json.loads((out / "batch.json").read_text())
    status = {j["name"]: j["status"] for j in record["jobs"]}
    assert status.pop("missing-log") == "error"
    assert status.pop("visual-rpy-impossible") == "gate_failed"
    assert set(status.values()) == {"passed"}, status
    assert len(status) == 7
    missing = next(j for j in record["jobs"] if j["name"] == "missing-log")
    assert "_not_there" in missing["error"]
    robots = {j["name"]: j for j in record["jobs"] if j["name"].startswith("ekf-mrclam-")}
    # Each robot's own log: five different trajectories.
    assert len({(out / n / "trajectory.tum").read_bytes() for n in robots}) == 5

    # junit.xml as an independent parser reads it.
    suites = list(JUnitXml.fromfile(str(out / "junit.xml")))
    assert len(suites) == 1
    suite = suites[0]
    assert (suite.tests, suite.failures, suite.errors) == (9, 1, 1)
    results = {case.name: case.result for case in suite}
    assert [type(r) for r in results["visual-rpy-impossible"]] == [Failure]
    assert [type(r) for r in results["missing-log"]] == [Error]
    assert all(results[name] == [] for name in status)
    assert all(case.classname in ("dense", "visual", "ekf") for case in suite)


def _some_jobs(manifest: str, names: set[str]) -> str:
    """``manifest`` with its [defaults] and only the [[job]] tables named ``names``."""
    head, *jobs = manifest.split("[[job]]")
    kept = [j for j in jobs if any(f'name = "{n}"' in j for n in names)]
    assert len(kept) == len(names)
    return head + "".join("[[job]]" + j for j in kept)


def test_shared_manifest_on_a_dask_cluster_gives_the_same_trajectories(
    shared_batch: dict[str, Any], tmp_path: Path
) -> None:
    """One job of each pipeline, and the one that cannot run, on a Dask cluster: the same
    trajectories as the local pool's, and the same exit code."""
    pytest.importorskip("distributed")
    from distributed import LocalCluster

    names = {"dense-rpy", "visual-rpy", "ekf-mrclam-3", "missing-log"}
    manifest = tmp_path / "ci.toml"
    manifest.write_text(_some_jobs(shared_batch["manifest"].read_text(), names))
    with LocalCluster(
        n_workers=2, threads_per_worker=1, host="127.0.0.1", dashboard_address=None
    ) as cluster:
        res = _batch(
            [
                str(manifest),
                "--out",
                str(tmp_path / "dask"),
                "--scheduler",
                cluster.scheduler_address,
            ]
        )
    assert res.exit_code == 1, res.output
    local, remote = _job_files(shared_batch["local"].out), _job_files(tmp_path / "dask")
    assert len(local) == 8 and len(remote) == 3
    assert remote == {name: local[name] for name in remote}


def test_resume_after_a_finished_batch_runs_nothing(
    shared_batch: dict[str, Any], tmp_path: Path
) -> None:
    import time

    from reference_runs import copy_out

    # Resumed in a copy: the finished batch is shared with the tests above.
    out = copy_out(shared_batch["local"], tmp_path / "local")
    before = {p: p.stat().st_mtime_ns for p in out.glob("*/run.json")}
    start = time.perf_counter()
    res = _batch([str(shared_batch["manifest"]), "--out", str(out), "--resume"])
    seconds = time.perf_counter() - start
    assert res.exit_code == 1, res.output  # the missing log is tried again and fails again
    record = json.loads((out / "batch.json").read_text())
    assert [j["name"] for j in record["jobs"] if not j["resumed"]] == ["missing-log"]
    assert {p: p.stat().st_mtime_ns for p in before} == before
    assert seconds < 20, seconds  # hashing the inputs and a failed open, no pipeline run
