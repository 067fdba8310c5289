"""Pieces every command shares: the error boundary and common option types."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, TypeVar

import typer

from slamcli.atomic import os_error
from slamcli.cli import render
from slamcli.errors import (
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


def exit_if_data_lost(outcome: RunOutcome) -> None:
    """Exit code 3 when a run finished but skipped frames or salvaged a damaged log."""
    from slamcli.run import data_loss_error

    error = data_loss_error(outcome)
    if error is not None:
        raise error
