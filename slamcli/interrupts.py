"""Ctrl-C around work that must not be cut in two, or that native code might swallow.

Both are Python-level SIGINT handlers, not signal masks: the kernel may hand SIGINT to any
thread (OpenBLAS and Open3D start their own), and only the Python handler is sure to see it.
Python runs signal handlers in the main thread only, so elsewhere a block runs as is.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator
from typing import Any


@contextlib.contextmanager
def watched(*, deferred: bool = False) -> Iterator[Callable[[], None]]:
    """Watch for Ctrl-C while the block runs; the yielded function raises KeyboardInterrupt
    when one came.

    Without ``deferred``, a Ctrl-C is delivered at once, as the handler before it would, and
    recorded: native code that polls for signals and clears them (pycolmap stops a solve on
    one) cannot make it vanish, since the next check raises it. With ``deferred`` it is held
    until the block ends, then delivered: the block is never cut in two.

    Either way, an exception that leaves the block after a Ctrl-C leaves it as
    KeyboardInterrupt: a Ctrl-C that broke a native call or an import half-way through
    surfaces as the interruption it was, not as that call's own error. Where Ctrl-C is ignored
    (or handled outside Python) the block runs as is.
    """
    received: list[int] = []

    def check() -> None:
        if received:
            raise KeyboardInterrupt

    previous = signal.getsignal(signal.SIGINT) if _main_thread() else None
    if previous is None or not (callable(previous) or previous == signal.SIG_DFL):
        yield check
        return

    def on_interrupt(signum: int, frame: Any) -> None:
        received.append(signum)
        if not deferred:
            _deliver(previous, signum, frame)

    signal.signal(signal.SIGINT, on_interrupt)
    try:
        yield check
    except KeyboardInterrupt:
        raise
    except BaseException as exc:
        if received:
            raise KeyboardInterrupt from exc
        raise
    finally:
        signal.signal(signal.SIGINT, previous)
    if received and deferred:
        _deliver(previous, signal.SIGINT, None)


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def _deliver(handler: Any, signum: int, frame: Any) -> None:
    """Hand a Ctrl-C to ``handler`` (a function, or the default action: KeyboardInterrupt)."""
    if callable(handler):
        handler(signum, frame)
    elif handler == signal.SIG_DFL:
        raise KeyboardInterrupt
