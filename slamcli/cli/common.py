"""Pieces every command shares: the error boundary and common option types."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, TypeVar

import typer

from slamcli.cli import render
from slamcli.errors import SlamcliError

F = TypeVar("F", bound=Callable[..., Any])

EXIT_OK, EXIT_INPUT, EXIT_USAGE, EXIT_DATA_LOST = 0, 1, 2, 3


def boundary(fn: F) -> F:
    """The CLI's one error boundary: a SlamcliError becomes a red line, a hint and an exit code."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return fn(*args, **kwargs)
        except SlamcliError as exc:
            render.error(exc)
            raise typer.Exit(exc.exit_code) from None
        except KeyboardInterrupt:
            render.err.print("[bold red]interrupted[/]")
            raise typer.Exit(130) from None

    return wrapper  # type: ignore[return-value]
