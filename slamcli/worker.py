"""A second process for CPU-heavy pure functions, with results taken at fixed points.

Python threads share one interpreter lock, and the libraries the pipelines lean on for their
heaviest steps (pycolmap's bundle adjustment among them) hold it while they compute: a thread
gains nothing there. :class:`SideProcess` runs such a function in one worker process instead,
while the caller goes on. The caller asks for the result at a point of its own work fixed by
the data (say, the next keyframe), never "when it is ready", so the output does not depend on
timing: the function is pure and deterministic, its result is the same in either process, and
the same point is used whether it ran there or in place.

The worker is ``python -m slamcli.worker [MODULE ...]``, fed pickled calls on its stdin, one
at a time. It imports the modules named first, while the caller goes on, so that the first
call's answer does not wait for them (the visual pipeline's, with numba, take half a second).
It is started with :mod:`subprocess`, not :mod:`multiprocessing`: it never re-imports the
caller's ``__main__`` (a script without a ``__main__`` guard stays safe), and it may be started
from a daemonic process such as a Dask worker's task. With ``parallel=False``, or where no
process can be started, or when the worker dies, the call runs in place instead: slower, same
result.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import pickle
import select
import signal
import struct
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from typing import IO, Any, Generic, TypeVar, cast

log = logging.getLogger(__name__)

T = TypeVar("T")

_HEADER = struct.Struct("<Q")
_READY = b"\x01"  # the worker's first byte: its modules are imported
_IN_PLACE = object()  # a call the worker did not answer: run it here


def _send(stream: IO[bytes], obj: object) -> None:
    data = pickle.dumps(obj, protocol=pickle.HIGHEST_PROTOCOL)
    stream.write(_HEADER.pack(len(data)))
    stream.write(data)
    stream.flush()


def _receive(stream: IO[bytes]) -> Any:
    head = stream.read(_HEADER.size)
    if len(head) < _HEADER.size:
        raise EOFError("the other end closed the pipe")
    (size,) = _HEADER.unpack(head)
    data = stream.read(size)
    if len(data) < size:
        raise EOFError("the other end closed the pipe mid-message")
    return pickle.loads(data)


class Pending(Generic[T]):
    """A call started by :meth:`SideProcess.submit`; :meth:`result` waits for it (or runs it
    in place when it could not be run apart)."""

    def __init__(
        self,
        fn: Callable[..., T],
        args: tuple[Any, ...],
        kwargs: dict[str, Any],
        owner: SideProcess | None,
        clock: SideProcess | None = None,
    ) -> None:
        self._fn, self._args, self._kwargs = fn, args, kwargs
        self._owner = owner
        self._clock = clock
        self._done = False
        self._value: Any = None

    def result(self) -> T:
        if not self._done:
            value: Any = self._owner._collect(self) if self._owner is not None else _IN_PLACE
            if value is _IN_PLACE:
                start = time.perf_counter()
                value = self._fn(*self._args, **self._kwargs)
                if self._clock is not None:
                    self._clock.in_place_s += time.perf_counter() - start
            self._value, self._done = value, True
        return cast(T, self._value)


class SideProcess:
    """One worker process (started on first use), or none with ``parallel=False``.

    ``preload`` names modules the worker imports as soon as it starts: those of the functions
    it will run and of the libraries they call. ``module:function`` also calls that function
    (without arguments) once the module is imported: to load compiled kernels, say.

    With ``in_place_while_starting``, a call submitted before the worker has imported its
    modules runs in place instead (when its result is asked for): the caller does not wait for
    the worker's start-up, and the result is the same. With ``start_after_s``, calls run in
    place until they have taken that long there (``in_place_s``), and only then is the worker
    started: a short job does not pay for starting it. Where a call runs never changes what
    it returns, so neither option changes a result.

    One call is outstanding at a time: :meth:`submit` first collects the previous call's
    result (so neither end ever blocks writing to a full pipe)."""

    def __init__(
        self,
        parallel: bool = True,
        preload: tuple[str, ...] = (),
        in_place_while_starting: bool = False,
        start_after_s: float = 0.0,
    ) -> None:
        self._parallel = parallel
        self._preload = preload
        self._in_place_while_starting = in_place_while_starting
        self._start_after_s = start_after_s
        self.in_place_s = 0.0
        """Seconds the calls run in place have taken."""
        self._proc: subprocess.Popen[bytes] | None = None
        self._ready = False
        self._outstanding: Pending[Any] | None = None

    def start(self) -> None:
        """Start the worker now (it takes a moment to import what it runs)."""
        if self._parallel and self._proc is None:
            try:
                self._proc = subprocess.Popen(
                    [sys.executable, "-m", "slamcli.worker", *self._preload],
                    stdin=subprocess.PIPE,
                    stdout=subprocess.PIPE,
                )
            except OSError as exc:
                log.warning("no worker process (%s); running in place", exc)
                self._parallel = False

    def submit(self, fn: Callable[..., T], *args: Any, **kwargs: Any) -> Pending[T]:
        """Start ``fn(*args, **kwargs)`` (a module-level function; arguments and result
        picklable)."""
        if self._outstanding is not None:
            self._outstanding.result()
        if self._proc is None and self.in_place_s < self._start_after_s:
            return Pending(fn, args, kwargs, None, clock=self)
        self.start()
        if self._proc is None:
            return Pending(fn, args, kwargs, None)
        if self._in_place_while_starting:
            try:
                if not self._started(wait=False):
                    return Pending(fn, args, kwargs, None, clock=self)
            except (OSError, EOFError) as exc:
                self._fail(exc)
                return Pending(fn, args, kwargs, None)
        pending: Pending[T] = Pending(fn, args, kwargs, self)
        try:
            assert self._proc.stdin is not None
            _send(self._proc.stdin, (fn, args, kwargs))
        except (OSError, pickle.PicklingError) as exc:
            self._fail(exc)
            return Pending(fn, args, kwargs, None)
        self._outstanding = pending
        return pending

    def _collect(self, pending: Pending[T]) -> Any:
        """The worker's answer to ``pending`` (``_IN_PLACE`` when it must run here)."""
        if self._outstanding is not pending or self._proc is None:
            return _IN_PLACE
        self._outstanding = None
        try:
            assert self._proc.stdout is not None
            self._started(wait=True)
            ok, value = _receive(self._proc.stdout)
        except (OSError, EOFError, pickle.UnpicklingError) as exc:
            self._fail(exc)
            return _IN_PLACE
        if not ok:
            raise value
        return value

    def _started(self, wait: bool) -> bool:
        """Whether the worker has imported its modules (it then writes one byte); with
        ``wait``, wait for it.

        Raises:
            EOFError: the worker ended first.
        """
        if self._ready:
            return True
        assert self._proc is not None and self._proc.stdout is not None
        if not wait:
            try:
                readable, _, _ = select.select([self._proc.stdout], [], [], 0)
            except (OSError, ValueError):
                readable = [True]  # a pipe select cannot watch: wait for it in _collect
            if not readable:
                return False
        # Nothing else is on the pipe before the worker's first answer.
        if self._proc.stdout.read(1) != _READY:
            raise EOFError("the worker ended as it started")
        self._ready = True
        return True

    def _fail(self, exc: BaseException) -> None:
        log.warning("the worker process stopped (%s); running in place", exc)
        self._parallel = False
        self.close()

    def close(self) -> None:
        """Stop the worker. Nothing it holds is needed any more (a call in progress is abandoned,
        imports still under way would only be finished), so it is killed rather than asked to
        end: the caller does not wait for it to finish importing or to tear itself down."""
        proc, self._proc = self._proc, None
        self._outstanding = None
        self._ready = False
        if proc is None:
            return
        proc.kill()
        for stream in (proc.stdin, proc.stdout):
            if stream is not None:
                with contextlib.suppress(OSError):
                    stream.close()
        proc.wait()

    def __enter__(self) -> SideProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        if self._proc is not None:
            self._proc.kill()


class Background(Generic[T]):
    """``fn(*args)`` on a daemon thread, for work that lets go of the interpreter lock (file
    reads, hashing); :meth:`result` waits for it and re-raises what it raised. A daemon thread
    never holds up the interpreter's exit (after Ctrl-C, say)."""

    def __init__(self, fn: Callable[..., T], *args: Any) -> None:
        self._outcome: tuple[bool, Any] = (False, None)
        self._thread = threading.Thread(target=self._run, args=(fn, args), daemon=True)
        self._thread.start()

    def _run(self, fn: Callable[..., T], args: tuple[Any, ...]) -> None:
        try:
            self._outcome = (True, fn(*args))
        except BaseException as exc:  # re-raised by result()
            self._outcome = (False, exc)

    def result(self) -> T:
        self._thread.join()
        ok, value = self._outcome
        if not ok:
            raise value
        return cast(T, value)


def _serve(preload: list[str]) -> None:
    """The worker's loop: a call in, ``(True, result)`` or ``(False, exception)`` out, until
    the caller closes the pipe. The modules ``preload`` names are imported first (and a
    ``module:function`` entry's function called)."""
    # Ctrl-C reaches the whole process group: the caller handles it (and closes the pipe).
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    stdin, stdout = sys.stdin.buffer, sys.stdout.buffer
    # Nothing else may write to the answer pipe.
    sys.stdout = sys.stderr
    for name in preload:
        module, _, function = name.partition(":")
        # A module that fails here fails again in the call that needs it, which reports it.
        with contextlib.suppress(Exception):
            loaded = importlib.import_module(module)
            if function:
                getattr(loaded, function)()
    try:
        stdout.write(_READY)
        stdout.flush()
    except (BrokenPipeError, OSError):
        return
    while True:
        try:
            fn, args, kwargs = _receive(stdin)
        except EOFError:
            return
        try:
            answer: tuple[bool, Any] = (True, fn(*args, **kwargs))
        except Exception as exc:
            answer = (False, exc)
        try:
            _send(stdout, answer)
        except (BrokenPipeError, OSError):
            return


if __name__ == "__main__":
    _serve(sys.argv[1:])
