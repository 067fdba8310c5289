"""The error hierarchy. Every failure a user can cause is a :class:`SlamcliError`.

Each error carries a one-line message (what was expected, what was found, where) and an
optional hint (what to do). The CLI maps ``exit_code`` to the process exit status:
0 ok, 1 bad input or config, 2 usage, 3 the run finished but lost data.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path


class SlamcliError(Exception):
    """Root of all errors slamcli raises on purpose."""

    exit_code = 1

    def __init__(self, msg: str, hint: str | None = None) -> None:
        super().__init__(msg)
        self.msg = msg
        self.hint = hint

    def __str__(self) -> str:
        return self.msg


class InputError(SlamcliError):
    """The input data is missing, unreadable or malformed."""


class UnknownFormatError(InputError):
    """No known source format matches the input path."""

    def __init__(self, path: str | Path, known: Sequence[str], detail: str = "") -> None:
        msg = f"{path}: not a recognised input" + (f" ({detail})" if detail else "")
        super().__init__(msg, hint=f"known formats: {', '.join(known)}")
        self.path = Path(path)


class FormatError(InputError):
    """A file does not follow its format; names the file and, where known, the line."""

    def __init__(
        self, path: str | Path, msg: str, line: int | None = None, hint: str | None = None
    ) -> None:
        where = f"{path}:{line}" if line is not None else str(path)
        super().__init__(f"{where}: {msg}", hint=hint)
        self.path = Path(path)
        self.line = line


class TopicNotFoundError(InputError):
    """A log has no topic (or several) matching what was asked for.

    ``candidates`` rows (topic, type, encoding, count, rate) are shown as a table by the CLI.
    It is bad input, exit code 1, like the other InputErrors: 2 is for command-line usage errors.
    """

    def __init__(
        self, msg: str, hint: str | None = None, candidates: Sequence[Sequence[str]] = ()
    ) -> None:
        super().__init__(msg, hint=hint)
        self.candidates = [list(map(str, row)) for row in candidates]


class ConfigError(SlamcliError):
    """A configuration key or command-line option has a bad value."""


class PipelineError(SlamcliError):
    """A pipeline could not produce a result."""


class MapError(SlamcliError):
    """An occupancy map is malformed or a query on it is impossible."""


class NoPathError(MapError):
    """No path exists between start and goal."""


class ExportError(SlamcliError):
    """An output could not be written."""


class DataLossError(SlamcliError):
    """Work finished, but some input was lost or a gate failed (``--strict`` or ``--fail-if``)."""

    exit_code = 3
