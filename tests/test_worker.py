"""The side process (slamcli.worker) and the frame read-ahead (slamcli.formats.base.ReadAhead):
same results as in place, errors where they happened, and nothing left behind."""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Iterator

import numpy as np
import pytest

from slamcli.formats.base import ReadAhead
from slamcli.worker import Background, SideProcess

# The worker imports what it runs by name, so the calls here are library functions: it does
# not see the tests folder.


def test_side_process_runs_apart_and_gives_what_running_in_place_gives() -> None:
    values = np.arange(1000, dtype=np.float64) / 7.0
    with SideProcess(parallel=True) as side:
        pid = side.submit(os.getpid).result()
        total = side.submit(np.cumsum, values, dtype=np.float64).result()
    assert pid != os.getpid()
    with SideProcess(parallel=False) as side:
        assert side.submit(os.getpid).result() == os.getpid()
        here = side.submit(np.cumsum, values, dtype=np.float64).result()
    assert np.array_equal(total, here)  # bit for bit


def test_the_worker_imports_the_modules_named_before_the_first_call() -> None:
    with SideProcess(preload=("slamcli.pipelines.visual.frames",)) as side:
        loaded = side.submit(eval, "'slamcli.pipelines.visual.frames' in __import__('sys').modules")
        assert loaded.result() is True


def test_side_process_answers_calls_in_order_one_at_a_time() -> None:
    with SideProcess() as side:
        first = side.submit(np.sum, np.ones(10))
        # A second call collects the first one's answer before it is sent.
        second = side.submit(np.sum, np.ones(20))
        assert second.result() == 20.0
        assert first.result() == 10.0


def test_an_error_in_the_worker_is_raised_by_result() -> None:
    with SideProcess() as side:
        pending = side.submit(int, "seventeen")
        with pytest.raises(ValueError, match="seventeen"):
            pending.result()
        # The worker is still there for the next call.
        assert side.submit(os.getpid).result() != os.getpid()


def test_a_dead_worker_falls_back_to_running_in_place(caplog: pytest.LogCaptureFixture) -> None:
    side = SideProcess()
    side.start()
    assert side._proc is not None
    side._proc.kill()
    side._proc.wait()
    assert side.submit(os.getpid).result() == os.getpid()
    assert side.submit(np.sum, np.ones(5)).result() == 5.0
    assert "running in place" in caplog.text
    side.close()


def test_closing_stops_the_worker_process() -> None:
    side = SideProcess()
    assert side.submit(np.sum, np.ones(2)).result() == 2.0
    proc = side._proc
    assert proc is not None and proc.poll() is None
    side.close()
    assert proc.poll() is not None


def _boom(message: str) -> None:
    raise ValueError(message)


def test_background_returns_the_value_and_re_raises_errors() -> None:
    assert Background(np.sum, np.ones(4)).result() == 4.0
    with pytest.raises(ValueError, match="late"):
        Background(_boom, "late").result()


def _frames(n: int, fail_at: int | None = None, log: list[int] | None = None) -> Iterator[int]:
    for i in range(n):
        if i == fail_at:
            raise OSError(f"frame {i}: unreadable")
        if log is not None:
            log.append(i)
        yield i


def test_read_ahead_keeps_the_order_and_reads_on_another_thread() -> None:
    threads: list[str] = []

    def frames() -> Iterator[int]:
        for i in range(50):
            threads.append(threading.current_thread().name)
            yield i

    with ReadAhead(frames(), depth=3) as reader:
        assert list(reader) == list(range(50))
    assert set(threads) == {"read-ahead"}


def test_read_ahead_raises_a_reading_error_where_it_happened() -> None:
    got = []
    with pytest.raises(OSError, match="frame 7"), ReadAhead(_frames(20, fail_at=7)) as reader:
        for frame in reader:
            got.append(frame)
    assert got == list(range(7))


def test_read_ahead_stops_reading_when_the_consumer_stops() -> None:
    read: list[int] = []
    with ReadAhead(_frames(10_000, log=read), depth=2) as reader:
        for frame in reader:
            if frame == 5:
                break
    time.sleep(0.05)
    # At most depth items queued beyond the one in hand, and the one being put.
    assert len(read) <= 5 + 1 + 2 + 1
    assert not any(t.name == "read-ahead" for t in threading.enumerate())


def test_a_call_before_the_worker_has_started_runs_in_place() -> None:
    """With in_place_while_starting, calls run here until the worker has imported its modules
    (its Python start alone takes longer than the first call below), then apart."""
    with SideProcess(
        preload=("slamcli.kernels:load_adjustment",), in_place_while_starting=True
    ) as side:
        side.start()
        assert side.submit(os.getpid).result() == os.getpid()
        deadline = time.monotonic() + 120
        pid = os.getpid()
        while pid == os.getpid() and time.monotonic() < deadline:
            time.sleep(0.05)
            pid = side.submit(os.getpid).result()
        assert pid != os.getpid()


@pytest.mark.parametrize("depth", [1, 2, 3])
def test_prefetch_hands_items_back_in_order_depth_behind(depth: int) -> None:
    """Prefetch works up to ``depth`` items ahead: an item comes back once ``depth`` more have
    been pushed (or at the drain), in order, with what preparing it in place gives."""
    from slamcli.formats.base import Prefetch

    ahead = Prefetch(np.cumsum, ahead=True, depth=depth)
    here = Prefetch(np.cumsum, ahead=False)
    got, want = [], []
    for i in range(7):
        item = np.arange(i + 1, dtype=np.float64)
        back = ahead.push(item)
        assert len(back) == (1 if i >= depth else 0)
        got += [r.result() for _, r in back]
        want += [r.result() for _, r in here.push(item)]
    got += [r.result() for _, r in ahead.drain()]
    ahead.close()
    assert len(got) == 7
    for a, b in zip(got, want, strict=True):
        assert np.array_equal(a, b)


def test_calls_run_in_place_until_they_have_taken_start_after_s() -> None:
    """With start_after_s, the worker is started only once the calls run in place have taken
    that long: before, a call runs here; after, apart."""
    with SideProcess(start_after_s=0.05) as side:
        assert side.submit(os.getpid).result() == os.getpid()
        side.submit(time.sleep, 0.06).result()  # here: 0.06 s of the 0.05
        assert side.in_place_s >= 0.06
        assert side.submit(os.getpid).result() != os.getpid()
