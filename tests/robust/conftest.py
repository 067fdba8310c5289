"""The robust suite's collection rule, its ``figures`` fixture and the table it ends with.

The suite runs only when it is named (``pytest tests/robust``, which ``make test-robust``
does): ``make test`` collects ``tests/`` and must not spend a quarter of an hour here.

Each test records every accuracy figure it checks with :meth:`Figures.expect` and ends with
:meth:`Figures.verify`, so one failing figure never hides the others; the session ends with a
table of every case, variant, figure and threshold, collected from all test processes.
"""

from __future__ import annotations

import json
import math
import operator
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
PROPERTY = "robust_figure"

_COMPARE: dict[str, Callable[[float, float], bool]] = {
    "<": operator.lt,
    "<=": operator.le,
    ">": operator.gt,
    ">=": operator.ge,
}


def _named(config: pytest.Config) -> bool:
    """Whether an argument of the command line is this folder or lies inside it."""
    base = config.invocation_params.dir
    for arg in config.args:
        path = (base / arg.split("::", 1)[0]).resolve()
        if path == HERE or HERE in path.parents:
            return True
    return False


def pytest_ignore_collect(collection_path: Path, config: pytest.Config) -> bool | None:
    if HERE in collection_path.parents and not _named(config):
        return True
    return None


@dataclass(frozen=True)
class Row:
    """One checked figure: ``value op threshold`` (``note`` says where the threshold comes
    from when it is not the main test's number)."""

    case: str
    variant: str
    figure: str
    value: float
    op: str
    threshold: float
    note: str = ""

    @property
    def passed(self) -> bool:
        return math.isfinite(self.value) and _COMPARE[self.op](self.value, self.threshold)


class Figures:
    """The figures one test checks, recorded on its report for the closing table."""

    def __init__(self, node: pytest.Item, case: str, variant: str) -> None:
        self._node = node
        self.case = case
        self.variant = variant
        self.rows: list[Row] = []

    def expect(self, figure: str, value: float, op: str, threshold: float, note: str = "") -> None:
        """Record ``value op threshold``; a failure is reported by :meth:`verify`."""
        row = Row(self.case, self.variant, figure, float(value), op, float(threshold), note)
        self.rows.append(row)
        self._node.user_properties.append((PROPERTY, json.dumps(asdict(row))))

    def verify(self) -> None:
        failed = [r for r in self.rows if not r.passed]
        assert not failed, "; ".join(
            f"{r.figure} = {r.value:.4g}, needs {r.op} {r.threshold:.4g}" for r in failed
        )


@pytest.fixture
def figures(request: pytest.FixtureRequest) -> Figures:
    """A :class:`Figures` named by the test (without ``test_``) and its parameters."""
    node = request.node
    assert isinstance(node, pytest.Item)
    case = node.name.split("[", 1)[0].removeprefix("test_")
    callspec = getattr(node, "callspec", None)
    return Figures(node, case, callspec.id if callspec is not None else "")


# -- the closing table -----------------------------------------------------------------------------

_rows: list[Row] = []
_broken: list[tuple[str, str]] = []
_prefix: list[str] = []


def pytest_configure(config: pytest.Config) -> None:
    _prefix.append(HERE.relative_to(config.rootpath).as_posix() + "/")


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    """Collect the rows of every test, whichever process ran it; a test that failed before
    recording a failing figure (the run raised) is listed with its error."""
    if not _prefix or not report.nodeid.startswith(_prefix[0]):
        return
    rows = [Row(**json.loads(v)) for k, v in report.user_properties if k == PROPERTY]
    if report.when == "call":
        _rows.extend(rows)
    if report.failed and not any(not r.passed for r in rows):
        message = str(report.longrepr).strip().splitlines()
        _broken.append((report.nodeid, message[-1] if message else "failed"))


def _order(variant: str) -> tuple[int, str]:
    known = ("noise", "drop-first", "drop-every-10th")
    seed, _, rest = variant.partition("-")
    if seed.isdigit():
        return (int(seed), rest)
    return (100 + known.index(variant) if variant in known else 200, variant)


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    if not _rows and not _broken:
        return
    header = ("case", "variant", "figure", "value", "threshold", "result")
    lines = [
        (
            r.case,
            r.variant,
            r.figure,
            f"{r.value:.4g}",
            f"{r.op} {r.threshold:.4g}" + (f" ({r.note})" if r.note else ""),
            "ok" if r.passed else "FAIL",
        )
        for r in sorted(_rows, key=lambda r: (r.case, _order(r.variant)))
    ]
    widths = [max(len(row[i]) for row in [header, *lines]) for i in range(len(header))]
    terminalreporter.write_sep("=", "accuracy on perturbed inputs and seeds")
    for row in [header, *lines]:
        terminalreporter.write_line(
            "  ".join(c.ljust(w) for c, w in zip(row, widths, strict=True)).rstrip()
        )
    failed = sum(1 for r in _rows if not r.passed)
    terminalreporter.write_line(f"{len(lines)} figures, {failed} over their threshold")
    for nodeid, message in _broken:
        terminalreporter.write_line(f"no figures from {nodeid}: {message}")
