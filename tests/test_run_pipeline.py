"""run_pipeline's steps: the map built from the run in memory, gates on the outcome, Ctrl-C
around native work, and a failed pipeline closed."""

from __future__ import annotations

import contextlib
import json
import signal
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from slamcli.errors import InputError, PipelineError
from slamcli.interrupts import watched
from slamcli.mapping.build import MapInput, build
from slamcli.run import RunOutcome, run_pipeline
from slamcli.types import Trajectory

REPO = Path(__file__).resolve().parents[1]
ROOM = REPO / "sample_data" / "rgbd_room"


@pytest.fixture(scope="module")
def mapped(tmp_path_factory: pytest.TempPathFactory) -> RunOutcome:
    """The sample room through frame-to-frame odometry, with its occupancy map."""
    return run_pipeline(ROOM, "odometry", tmp_path_factory.mktemp("run") / "room", build_map=True)


def test_map_takes_each_frame_at_the_pose_the_run_gave_it(mapped: RunOutcome) -> None:
    report = json.loads((mapped.run_dir / "map.json").read_text())
    assert mapped.result.trajectory is not None
    poses = len(mapped.result.trajectory)
    assert poses == mapped.counts["frames_processed"] == 30
    assert report["frames"] == {
        "read": 30,
        "used": poses,
        "without_pose": 0,
        "frame_step": 1,
        "pixel_step": 4,
    }
    # The floor was found in the run's own points, and the record names the final folder.
    assert report["run"] == str(mapped.run_dir)
    assert mapped.record["outputs"][-5:] == [
        "map.yaml",
        "map.pgm",
        "map.png",
        "map.json",
        "run.json",
    ]
    assert [p.name for p in mapped.outputs] == mapped.record["outputs"]


def test_a_pose_a_few_ms_off_the_frame_is_no_pose_of_that_frame(mapped: RunOutcome) -> None:
    """A file's stamps are rounded, so a folder's map matches within 20 ms; the run's own poses
    belong to their frames exactly, and a stamp 5 ms off belongs to no frame."""
    traj = mapped.result.trajectory
    assert traj is not None
    result = replace(
        mapped.result, trajectory=Trajectory(traj.stamps_ns + 5_000_000, traj.world_from_body)
    )
    given = MapInput.from_result("odometry", result, ROOM, {}, mapped.run_dir)
    with pytest.raises(
        InputError, match=r"none of its 30 depth frames has a pose in the run's trajectory$"
    ):
        build(given)


def test_gates_read_the_outcome_not_the_folder(mapped: RunOutcome, monkeypatch: Any) -> None:
    """run.json as written is in RunOutcome.record: a job's gates and figures come from it."""
    from slamcli.batch import job as jobs

    def no_reading(_: Path) -> None:
        raise AssertionError("run.json read back from disk")

    monkeypatch.setattr(jobs, "read_run_json", no_reading)
    job = jobs.RunJob("odometry", ROOM, mapped.run_dir, fail_if=("frames.lost > 100",))
    result = jobs.result_from_run(job, mapped.record, 1.0)
    assert result.status == "passed" and result.gates[0].failed is False
    assert result.metrics["frames.processed"] == 30
    on_disk = json.loads((mapped.run_dir / "run.json").read_text())
    assert on_disk == mapped.record


# -- Ctrl-C --------------------------------------------------------------------------------------


@pytest.fixture
def interactive() -> Any:
    """Ctrl-C handled and delivered, as in a shell: a test runner's worker process may have
    SIGINT ignored or blocked (set by the runner or left by a library), which these tests
    must not inherit. Both are put back afterwards."""
    handler = signal.signal(signal.SIGINT, signal.default_int_handler)
    blocked = signal.pthread_sigmask(signal.SIG_UNBLOCK, [signal.SIGINT])
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
        signal.signal(signal.SIGINT, handler)


@pytest.mark.usefixtures("interactive")
def test_an_error_after_ctrl_c_leaves_as_the_interrupt() -> None:
    """A Ctrl-C that breaks a native call half-way (an import, a solve) surfaces as the
    interruption, with the call's own error as its cause."""
    with pytest.raises(KeyboardInterrupt) as caught, watched(deferred=True):
        signal.raise_signal(signal.SIGINT)
        raise RuntimeError("Cannot import the C++ backend")
    assert isinstance(caught.value.__cause__, RuntimeError)


def test_an_error_without_ctrl_c_stays_itself() -> None:
    with pytest.raises(RuntimeError), watched():
        raise RuntimeError("a real failure")


@pytest.mark.usefixtures("interactive")
def test_a_deferred_ctrl_c_waits_for_the_block_and_a_swallowed_one_is_checked() -> None:
    done = []
    with pytest.raises(KeyboardInterrupt), watched(deferred=True):
        signal.raise_signal(signal.SIGINT)
        done.append("rest of the block")
    assert done == ["rest of the block"]

    def swallowed(check: Any) -> None:
        # As a native solver that stops on the signal and clears it.
        with contextlib.suppress(KeyboardInterrupt):
            signal.raise_signal(signal.SIGINT)
        check()

    with pytest.raises(KeyboardInterrupt), watched() as check:
        swallowed(check)


@pytest.mark.usefixtures("interactive")
def test_ctrl_c_ignored_stays_ignored() -> None:
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        with watched() as check:
            signal.raise_signal(signal.SIGINT)
            check()
        with watched(deferred=True):
            signal.raise_signal(signal.SIGINT)
    finally:
        signal.signal(signal.SIGINT, previous)


# -- a failing pipeline ---------------------------------------------------------------------------


def test_a_pipeline_that_fails_is_closed(tmp_path: Path, monkeypatch: Any) -> None:
    from slamcli.pipelines.visual import VisualSlam

    closed: list[bool] = []
    real_close = VisualSlam.close

    def finish(self: VisualSlam) -> Any:
        raise PipelineError("made to fail")

    def close(self: VisualSlam) -> None:
        closed.append(True)
        real_close(self)

    monkeypatch.setattr(VisualSlam, "finish", finish)
    monkeypatch.setattr(VisualSlam, "close", close)
    with pytest.raises(PipelineError, match="made to fail"):
        run_pipeline(ROOM, "visual", tmp_path / "run", max_frames=3)
    assert closed == [True]
    assert not (tmp_path / "run").exists()
