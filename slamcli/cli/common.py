"""Pieces every command shares: the error boundary and common option types."""

from __future__ import annotations

import errno
import functools
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TypeVar

import typer

from slamcli.atomic import UNWRITABLE_HINT
from slamcli.cli import render
from slamcli.errors import (
    ExportError,
    InputError,
    SlamcliError,
    TopicNotFoundError,
)

if TYPE_CHECKING:
    from slamcli.run import RunOutcome

F = TypeVar("F", bound=Callable[..., Any])

EXIT_OK, EXIT_INPUT, EXIT_USAGE, EXIT_DATA_LOST = 0, 1, 2, 3


def boundary(fn: F) -> F:
    """The CLI's one error boundary: a SlamcliError becomes a red line, a hint and an exit code."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except TopicNotFoundError as exc:
            render.error(exc)
            if exc.candidates:
                render.table(
                    "Candidates",
                    ["topic", "type", "encoding", "count", "rate Hz"],
                    exc.candidates,
                    right_align=["count", "rate Hz"],
                    stderr=True,
                )
            raise typer.Exit(exc.exit_code) from None
        except SlamcliError as exc:
            render.error(exc)
            raise typer.Exit(exc.exit_code) from None
        except OSError as exc:
            error = os_error(exc)
            render.error(error)
            raise typer.Exit(error.exit_code) from None
        except KeyboardInterrupt:
            render.err.print("[bold red]interrupted[/]")
            raise typer.Exit(130) from None

    return wrapper  # type: ignore[return-value]


_WRITE_ERRNOS = {
    errno.ENOSPC,
    errno.EROFS,
    errno.EFBIG,
    *([errno.EDQUOT] if hasattr(errno, "EDQUOT") else []),
}
_ACCESS_ERRNOS = {errno.EACCES, errno.EPERM}


def os_error(exc: OSError) -> SlamcliError:
    """A one-line error for an operating-system failure no library code turned into a
    SlamcliError: the path it names and the system's reason, with a hint where the reason
    tells what to do (a full or read-only disk: write elsewhere; permissions: check them)."""
    reason = exc.strerror or str(exc) or type(exc).__name__
    msg = reason
    if exc.filename is not None:
        where = str(exc.filename)
        if exc.filename2 is not None:
            where += f" -> {exc.filename2}"
        msg = f"{where}: {reason}"
    if exc.errno in _WRITE_ERRNOS:
        return ExportError(msg, hint=UNWRITABLE_HINT)
    if exc.errno in _ACCESS_ERRNOS:
        return InputError(msg, hint="check the permissions of that file or folder")
    return InputError(msg)


def exit_if_data_lost(outcome: RunOutcome) -> None:
    """Exit code 3 when a run finished but skipped frames or salvaged a damaged log."""
    from slamcli.run import data_loss_error

    error = data_loss_error(outcome)
    if error is not None:
        raise error
