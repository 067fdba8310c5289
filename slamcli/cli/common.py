"""Pieces every command shares: the error boundary and common option types."""

from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

import typer

from slamcli.atomic import UNWRITABLE_HINT
from slamcli.cli import render
from slamcli.errors import DataLossError, ExportError, SlamcliError, TopicNotFoundError

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


def os_error(exc: OSError) -> SlamcliError:
    """A one-line error for an operating-system failure no library code turned into a
    SlamcliError: the path it names and the system's reason. Writing is the usual culprit
    (permissions, a full disk), so the hint is about the output location."""
    reason = exc.strerror or str(exc) or type(exc).__name__
    if exc.filename is None:
        return ExportError(reason, hint=UNWRITABLE_HINT)
    where = str(exc.filename)
    if exc.filename2 is not None:
        where += f" -> {exc.filename2}"
    return ExportError(f"{where}: {reason}", hint=UNWRITABLE_HINT)


def exit_if_data_lost(outcome: RunOutcome, input: Path) -> None:
    """Exit code 3 when a run finished but skipped frames or salvaged a damaged log."""
    skipped = outcome.counts.get("frames_skipped", 0)
    if skipped:
        raise DataLossError(
            f"{input}: {skipped} frame(s) skipped because they were missing or unreadable; "
            "the results above exclude them",
            hint=f"'slamcli info {input} --deep' names every unreadable image",
        )
    if outcome.data_loss:
        raise DataLossError(
            f"{input}: the log is damaged; the run used what could be read",
            hint="--strict stops instead; 'mcap recover' can rebuild a damaged MCAP file",
        )
