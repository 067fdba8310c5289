"""Every example in README.md and in docs/, run as one walkthrough, the way a new user follows them.

The examples are the ``slamcli …`` lines of ```sh blocks, the ``$ …`` lines of ```text blocks
(the lines after one are its shown output) and the ```python blocks. The pages are walked in the
order of ``ORDER``: README.md first, then the docs pages, each from top to bottom. They run in a
scratch checkout: ``root/main`` with ``sample_data`` linked to the repository's and
``root/shared/data`` linked to the real data, so ``sample_data/…`` and ``../shared/data/…``
resolve as in a fresh clone, and later examples find the files earlier ones wrote, across pages
(``runs/demo`` from docs/demo.md, ``runs/room`` from docs/dense.md, …).

An example passes when it exits with 0 (1 when the page shows it printing an ``error:``, 3 when
its line says ``# exit code 3``), prints no traceback, the files it lists under ``Written``
exist, and what it prints is what the page shows (:func:`output_problem`): line for line and
word for word, with paths, times, byte sizes and hashes free to differ, and figures within a
tolerance (:data:`REL_TOL`), so the pages cannot drift from what the commands print.

``slamcli`` lines run in this process through typer's ``CliRunner`` (``slamcli … > FILE`` writes
the captured stdout to FILE), so the libraries are imported once rather than once per example;
what their helper processes print on stderr is read back from file descriptor 2. Shell lines and
Python blocks run in processes of their own, as a reader would run them.
"""

from __future__ import annotations

import contextlib
import os
import re
import shlex
import signal
import subprocess
import sys
import threading
import traceback
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from conftest import SHARED_DATA, shared_path
from reference_runs import copy_out, out_argument, shareable_example
from typer.testing import CliRunner

from slamcli.cli.app import app

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"

# The walkthrough's order. A page may use files that the examples of an earlier page wrote, so a
# new page goes after the pages it builds on; a page with examples missing here fails
# test_every_page_with_examples_is_walked.
ORDER = (
    "README.md",
    "docs/demo.md",  # runs/demo
    "docs/dense.md",  # runs/room, room.mcap; mesh export reads runs/demo
    "docs/visual.md",
    "docs/landmark-slam.md",  # runs/mrclam2
    "docs/lidar.md",  # runs/ccny, ccny.mcap
    "docs/maps.md",  # reads runs/room and runs/mrclam2
    "docs/planning.md",
    "docs/formats.md",
    "docs/convert.md",  # reads runs/room
    "docs/evaluation.md",
    "docs/graph-optimize.md",
    "docs/batch.md",
    "docs/synth.md",  # runs/world3, runs/world3_r2
    "docs/merge.md",  # reads runs/world3, runs/world3_r2
    "docs/python-api.md",
)

# The checkout's path as the pages show it (the demo prints the sample data's absolute path).
PAGES_CHECKOUT = "/work/main"
# Figures (numbers with a decimal point: accuracy, lengths, rates) may differ by this fraction of
# the page's value, or by one unit of its last digit: floating-point rounding differs across CPUs
# and library builds, and a tracker's choices follow it (DESIGN, section 6). Whole numbers (counts,
# cells, frames) are compared exactly; wall-clock times, byte sizes and hashes not at all.
REL_TOL = 0.25

# Each example may take a while (a dense run over the 150-frame TUM excerpt takes ~30 s), but
# none should take minutes.
TIMEOUT_S = 300
MIN_EXAMPLES = 70
ENV = {"NO_COLOR": "1", "MPLBACKEND": "Agg", "COLUMNS": "100"}

_FENCE = re.compile(r"^```(\w*)\s*$")
_HEADING = re.compile(r"^#{1,6}\s+(.*?)\s*$")
_EXIT_CODE = re.compile(r"#.*\bexit code (\d)\b")
_WRITTEN = re.compile(r"^\s*\d+ bytes\s+(\S+)\s*$")
_DOCS_LINK = re.compile(r"\]\((docs/[^)#\s]+)")


@dataclass
class Example:
    """One example of a page: a command line (or a Python script) and what the page shows."""

    page: str
    section: str
    line: int
    kind: str  # "slamcli", "shell" or "python"
    text: str
    output: list[str] = field(default_factory=list)
    expected_rc: int = 0

    def label(self) -> str:
        first = self.text.splitlines()[0] if self.text else ""
        return f"{self.page}:{self.line} ({self.section}): {first}"

    def written(self) -> list[str]:
        """The paths the shown output lists under a ``Written`` header."""
        paths: list[str] = []
        in_written = False
        for out in self.output:
            if out.strip() == "Written":
                in_written = True
                continue
            m = _WRITTEN.match(out)
            if in_written and m:
                paths.append(m.group(1))
            else:
                in_written = False
        return paths


def _joined(lines: list[str], i: int) -> tuple[str, int]:
    """The command starting at ``lines[i]`` with its ``\\`` continuation lines; the next index."""
    parts = [lines[i]]
    while parts[-1].rstrip().endswith("\\") and i + 1 < len(lines):
        parts[-1] = parts[-1].rstrip()[:-1]
        i += 1
        parts.append(lines[i])
    return " ".join(p.strip() for p in parts), i + 1


def parse_page(page: str, text: str) -> list[Example]:
    """The examples of one page (``page`` names it, relative to the repository) in order."""
    examples: list[Example] = []
    lines = text.splitlines()
    section = "top"
    i = 0
    while i < len(lines):
        heading = _HEADING.match(lines[i])
        fence = _FENCE.match(lines[i])
        if heading:
            section = heading.group(1).replace("`", "")
            i += 1
            continue
        if not fence:
            i += 1
            continue
        lang = fence.group(1)
        start = i + 1
        end = start
        while end < len(lines) and not lines[end].startswith("```"):
            end += 1
        body = lines[start:end]
        if lang == "python":
            examples.append(Example(page, section, start + 1, "python", "\n".join(body) + "\n"))
        elif lang == "sh":
            j = 0
            while j < len(body):
                command, nxt = _joined(body, j)
                if command.startswith("slamcli "):
                    rc = _EXIT_CODE.search(command)
                    examples.append(
                        Example(
                            page,
                            section,
                            start + j + 1,
                            "slamcli",
                            command,
                            expected_rc=int(rc.group(1)) if rc else 0,
                        )
                    )
                j = nxt
        elif lang == "text":
            j = 0
            while j < len(body):
                if not body[j].startswith("$ "):
                    j += 1
                    continue
                command, nxt = _joined(body, j)
                command = command[2:].strip()
                out_end = nxt
                while out_end < len(body) and not body[out_end].startswith("$ "):
                    out_end += 1
                output = body[nxt:out_end]
                rc = _EXIT_CODE.search(command)
                if rc:
                    expected = int(rc.group(1))
                elif output and output[0].startswith("error:"):
                    expected = 1
                else:
                    expected = 0
                kind = "slamcli" if command.startswith("slamcli ") else "shell"
                examples.append(
                    Example(page, section, start + j + 1, kind, command, output, expected)
                )
                j = out_end
        i = end + 1
    return examples


def _read(page: str) -> str:
    return (REPO / page).read_text(encoding="utf-8")


def _docs_pages() -> list[str]:
    return sorted(p.relative_to(REPO).as_posix() for p in DOCS.rglob("*.md"))


EXAMPLES = [e for page in ORDER if (REPO / page).exists() for e in parse_page(page, _read(page))]
SECTIONS = list(dict.fromkeys((e.page, e.section) for e in EXAMPLES))


def _section_id(page: str, section: str) -> str:
    return page + "#" + re.sub(r"[^A-Za-z0-9]+", "-", section).strip("-").lower()


def test_examples_are_found() -> None:
    """The extraction finds every kind of example; a reshuffle of the pages cannot drop them."""
    assert len(EXAMPLES) >= MIN_EXAMPLES, [e.label() for e in EXAMPLES]
    kinds = {e.kind for e in EXAMPLES}
    assert {"slamcli", "shell", "python"} <= kinds
    assert any(e.written() for e in EXAMPLES)
    assert any(e.expected_rc == 1 for e in EXAMPLES)
    readme = [e for e in EXAMPLES if e.page == "README.md"]
    assert any(e.kind == "slamcli" and e.written() for e in readme), "README.md shows no run"
    ids = [_section_id(*s) for s in SECTIONS]
    assert len(set(ids)) == len(ids), "two sections of a page share a heading"


def test_every_page_with_examples_is_walked() -> None:
    """Every docs page that holds examples is in ORDER, and every page in ORDER exists."""
    assert ORDER[0] == "README.md"
    absent = [page for page in ORDER if not (REPO / page).exists()]
    assert not absent, f"ORDER names pages that do not exist: {absent}"
    unwalked = [p for p in _docs_pages() if p not in ORDER and parse_page(p, _read(p))]
    assert not unwalked, (
        f"docs pages with examples that ORDER does not name: {unwalked}; add each to ORDER "
        "after the pages whose files its examples use"
    )


def test_readme_links_every_docs_page() -> None:
    """The README's links reach every docs page, so none is left where nobody finds it."""
    linked = set(_DOCS_LINK.findall(_read("README.md")))
    unlinked = [p for p in _docs_pages() if p not in linked]
    assert not unlinked, f"README.md does not link {unlinked}"


def test_output_comparison() -> None:
    """Wording, layout and counts are held to the page; times, sizes, paths as :func:`_as_given`
    writes them and small differences in figures are not."""
    shown = [
        "Plan",
        " map                runs/plan/map.yaml",
        " grid cost          4.414 m (81 cells, 21 expanded, jps)",
        " plan time          76 ms",
        " time    1.92 s",
        "Written",
        "  1531 bytes  runs/plan/path.csv",
        "hint: known formats: landmarks, mcap, tum",
    ]
    printed = [
        "",
        "Plan",
        " map                runs/plan/map.yaml   ",
        " grid cost          4.52 m (81 cells, 21 expanded, jps)",
        " plan time          312 ms",
        " time    0.5 s",
        "Written",
        " 11531 bytes  runs/plan/path.csv",
        "hint: known formats: landmarks, mcap, tum",
    ]
    assert output_problem(shown, "\n".join(printed)) is None
    for at, changed in (
        (3, " grid cost          9.9 m (81 cells, 21 expanded, jps)"),
        (3, " grid cost          4.414 m (82 cells, 21 expanded, jps)"),
        (8, "hint: known formats: carmen, landmarks, mcap, tum"),
        (6, "Written files"),
    ):
        drifted = [*printed[:at], changed, *printed[at + 1 :]]
        assert output_problem(shown, "\n".join(drifted)) is not None, changed
    assert output_problem(shown, "\n".join(printed[:-1])) is not None
    assert output_problem(["error: a (b; …)"], "error: a (b; c; d)") is None
    assert output_problem(["error: a (c; …)"], "error: a (b; c; d)") is not None
    settings = "[ekf]\nx = 1\nsmooth = true\ny = 2"
    assert output_problem(["[ekf]", "…", "smooth = true", "…"], settings) is None
    assert output_problem(["[ekf]", "…", "smooth = true"], settings) is not None
    out = Path("/tmp/shared-runs/plan-0123456789ab/out")
    cropped = f" map                {str(out)[:20]}…"
    given = _as_given(cropped, _paths_as_given(["plan", "--out", "runs/plan"], REPO, out))
    assert output_problem([shown[1]], given) is None


def _argv(command: str) -> tuple[list[str], str | None]:
    """The arguments of a ``slamcli`` line (comments stripped) and the file a ``>`` sends
    stdout to."""
    tokens = shlex.split(command, comments=True)
    target = None
    if ">" in tokens:
        at = tokens.index(">")
        if at != len(tokens) - 2:
            raise ValueError(f"only 'slamcli … > FILE' redirection is supported: {command}")
        target = tokens[at + 1]
        tokens = tokens[:at]
    assert tokens[0] == "slamcli"
    return tokens[1:], target


@dataclass
class _Outcome:
    returncode: int
    stdout: str
    stderr: str
    traceback: str = ""
    output: str = ""  # stdout and stderr as a terminal shows them, paths as the page gives them


_WALL_CLOCK = re.compile(r"^\s*(?:plan )?time\s+\d")
_NUMBER = re.compile(r"(?<![\w.])[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?(?![\w.]*\d)")
_FREE_UNIT = re.compile(r"\s*(?:ms\b|bytes\b|[KMG]iB\b)")
_HASH = re.compile(r"\b(?=[0-9]*[a-f])[0-9a-f]{12,}\b")
_BOX_RUN = re.compile(r"([━─═])\1+")
_SPACES = re.compile(r"\s+")


def _normalised(line: str) -> str:
    """A line with hashes masked and runs of spaces and of table rules shortened: column
    widths follow the widths of the figures in them."""
    line = _HASH.sub("<hash>", line.rstrip())
    return _SPACES.sub(" ", _BOX_RUN.sub(r"\1", line))


def _template(line: str) -> tuple[str, list[tuple[str, bool]]]:
    """The line with its numbers replaced by ``#``, and each number with whether it is free
    (a time in ms, a byte size, anything on a wall-clock ``time`` line)."""
    clock = bool(_WALL_CLOCK.match(line))
    numbers = []
    for m in _NUMBER.finditer(line):
        numbers.append((m.group(), clock or bool(_FREE_UNIT.match(line, m.end()))))
    return _NUMBER.sub("#", line), numbers


def _numbers_agree(shown: str, printed: str) -> bool:
    if "." not in shown and "." not in printed:
        return shown == printed
    a, b = float(shown), float(printed)
    decimals = len(shown.partition(".")[2])
    return abs(a - b) <= max(REL_TOL * abs(a), 10.0**-decimals)


def _line_problem(shown: str, printed: str) -> str | None:
    """Why the printed line is not the shown one, or None."""
    if "…" in shown:
        # The page elides part of a long line: the parts it shows are printed, in order.
        parts = [re.escape(part) for part in shown.split("…")]
        return None if re.fullmatch(".*".join(parts), printed) else "differs around the '…'"
    if printed.endswith("…"):
        # A table cell cropped to the terminal (see _as_given).
        return None if shown.startswith(printed[:-1]) else "differs before the cropped end"
    shown_template, shown_numbers = _template(shown)
    printed_template, printed_numbers = _template(printed)
    if shown_template != printed_template:
        return "wording or layout differs"
    for (a, free), (b, _) in zip(shown_numbers, printed_numbers, strict=True):
        if not free and not _numbers_agree(a, b):
            return f"{a} shown, {b} printed"
    return None


def _elided_problem(expected: list[str], actual: list[str]) -> str | None:
    """Why ``actual`` does not match ``expected``, whose ``…`` lines stand for any number of
    lines: the parts between them are printed in order, the first at the start, the last at
    the end."""
    parts: list[list[str]] = [[]]
    for line in expected:
        if line == "…":
            parts.append([])
        else:
            parts[-1].append(line)

    def matches(part: list[str], at: int) -> bool:
        block = actual[at : at + len(part)]
        return len(block) == len(part) and all(
            _line_problem(a, b) is None for a, b in zip(part, block, strict=True)
        )

    first, *middle, last = parts
    if not matches(first, 0):
        return f"the lines before the first '…' differ: {first}"
    at = len(first)
    for part in middle:
        found = next((k for k in range(at, len(actual)) if matches(part, k)), None)
        if found is None:
            return f"not printed after line {at}: {part}"
        at = found + len(part)
    if len(actual) - len(last) < at or not matches(last, len(actual) - len(last)):
        return f"the lines after the last '…' differ: {last}"
    return None


def output_problem(shown: list[str], printed: str) -> str | None:
    """What differs between the output a page shows and the one a command printed, or None.

    Both are compared line for line after :func:`_normalised`; numbers as :data:`REL_TOL` says.
    Blank lines around the output do not count. A ``…`` in a shown line stands for any text,
    a line that is only ``…`` for any number of lines.
    """
    expected = "\n".join(_normalised(line) for line in shown).strip("\n").split("\n")
    actual = "\n".join(_normalised(line) for line in printed.splitlines()).strip("\n").split("\n")
    if "…" in expected:
        why = _elided_problem(expected, actual)
        return None if why is None else f"printed output differs from the page: {why}"
    problems = []
    for k in range(max(len(expected), len(actual))):
        a = expected[k] if k < len(expected) else "<nothing>"
        b = actual[k] if k < len(actual) else "<nothing>"
        why = _line_problem(a, b) if k < min(len(expected), len(actual)) else "missing line"
        if why:
            problems.append(f"  line {k + 1}: {why}\n    page:    {a}\n    printed: {b}")
    if not problems:
        return None
    return "printed output differs from the page:\n" + "\n".join(problems[:12])


def _as_given(text: str, replacements: dict[str, str]) -> str:
    """``text`` with each absolute path of ``replacements`` written as the page gives it,
    longest first.

    Rich crops a table cell too wide for the terminal with ``…``: a shared run's long
    temporary ``--out`` may be cut inside. A line that ends with the start of such a path and
    ``…`` gets the page's path and ``…``, and is compared up to there.
    """
    longest_first = sorted(replacements, key=len, reverse=True)
    for absolute in longest_first:
        text = text.replace(absolute, replacements[absolute])
    lines = []
    for line in text.splitlines():
        head = line.rstrip()
        if head.endswith("…"):
            for absolute in longest_first:
                start = _cut_start(head[:-1], absolute)
                if start is not None:
                    head = head[:start] + replacements[absolute] + "…"
                    break
        lines.append(head)
    return "\n".join(lines)


def _cut_start(text: str, path: str) -> int | None:
    """Where ``text`` ends with a cut-off start of ``path`` (at least 8 characters, after a
    space), or None."""
    for k in range(len(path), 7, -1):
        if text.endswith(path[:k]) and text[: len(text) - k].endswith(" "):
            return len(text) - k
    return None


def _paths_as_given(args: list[str], work: Path, out: Path | None = None) -> dict[str, str]:
    """How paths a command prints map back to the page's words: the repository and the scratch
    checkout to :data:`PAGES_CHECKOUT`; for a shared run (run elsewhere, on absolute paths),
    each argument that names a path, and the run's own ``--out``, to the example's argument."""
    replacements = {str(REPO): PAGES_CHECKOUT, str(work): PAGES_CHECKOUT}
    if out is not None:
        given = out_argument(args)
        assert given is not None
        replacements[str(out)] = given.rstrip("/")
        for token in args:
            path = work / token
            if not token.startswith("-") and path.exists():
                replacements[str(path.resolve())] = token
    return replacements


@contextlib.contextmanager
def _console_width(columns: int) -> Iterator[None]:
    """The CLI's consoles ``columns`` wide while an example runs in this process. They take
    their width from the terminal when they are made, and a test process may have none (CI
    has no terminal at all: 80 columns), where the pages show a terminal's ``ENV`` width."""
    from slamcli.cli import render

    consoles = (render.out, render.err)
    saved = [c.width for c in consoles]
    for c in consoles:
        c.width = columns
    try:
        yield
    finally:
        for c, width in zip(consoles, saved, strict=True):
            c.width = width


@contextlib.contextmanager
def _inside(work: Path) -> Iterator[None]:
    """Run with ``work`` as the working directory, and a Python traceback after TIMEOUT_S."""
    before = Path.cwd()
    os.chdir(work)
    timed = threading.current_thread() is threading.main_thread()

    def expire(_signum: int, _frame: object) -> None:
        raise TimeoutError(f"still running after {TIMEOUT_S} s")

    previous = signal.signal(signal.SIGALRM, expire) if timed else None
    if timed:
        signal.alarm(TIMEOUT_S)
    try:
        yield
    finally:
        if timed:
            signal.alarm(0)
            signal.signal(signal.SIGALRM, previous)
        os.chdir(before)


def _run_slamcli(
    example: Example, work: Path, capfd: pytest.CaptureFixture[str], shared_run: Any
) -> _Outcome:
    args, target = _argv(example.text)
    if target is None and shareable_example(args, work):
        # A command other tests run too (the demo, the reference runs on the TUM excerpt, on
        # MRCLAM, ...): run once per session, its --out copied here for later examples.
        out = out_argument(args)
        assert out is not None
        run = shared_run(*args, cwd=work, suffix=Path(out).suffix)
        if run.out.exists():
            copy_out(run, work / out)
        output = _as_given(run.output, _paths_as_given(args, work, run.out))
        return _Outcome(run.exit_code, run.stdout, run.stderr, run.traceback, output)
    capfd.readouterr()
    with _inside(work), _console_width(int(ENV["COLUMNS"])):
        result = CliRunner().invoke(app, args, env=ENV)
    helpers = capfd.readouterr()  # what helper processes wrote to the inherited descriptors
    if target is not None:
        (work / target).write_text(result.stdout, encoding="utf-8")
    trace = ""
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        assert result.exc_info is not None
        trace = "".join(traceback.format_exception(*result.exc_info))
    output = _as_given(result.output + helpers.err, _paths_as_given(args, work))
    return _Outcome(result.exit_code, result.stdout, result.stderr + helpers.err, trace, output)


def _run_process(example: Example, work: Path) -> _Outcome:
    env = dict(os.environ, **ENV)
    kwargs = dict(cwd=work, env=env, capture_output=True, text=True, timeout=TIMEOUT_S)
    if example.kind == "python":
        name = re.sub(r"[^A-Za-z0-9]+", "_", example.page)
        script = work / f"example_{name}_{example.line}.py"
        script.write_text(example.text, encoding="utf-8")
        proc = subprocess.run([sys.executable, script.name], check=False, **kwargs)
    else:
        proc = subprocess.run(["bash", "-c", example.text], check=False, **kwargs)
    output = _as_given(proc.stdout + proc.stderr, _paths_as_given([], work))
    return _Outcome(proc.returncode, proc.stdout, proc.stderr, output=output)


def _check(
    example: Example, work: Path, capfd: pytest.CaptureFixture[str], shared_run: Any
) -> str | None:
    """What is wrong with the example's run, or None."""
    if example.kind == "slamcli":
        run = _run_slamcli(example, work, capfd, shared_run)
    else:
        run = _run_process(example, work)
    tail = f"\n--- stdout ---\n{run.stdout[-3000:]}\n--- stderr ---\n{run.stderr[-3000:]}"
    if run.traceback or "Traceback" in run.stderr:
        return f"{example.label()}: traceback{tail}\n{run.traceback}"
    if run.returncode != example.expected_rc:
        return (
            f"{example.label()}: exit code {run.returncode}, "
            f"the page expects {example.expected_rc}{tail}"
        )
    if example.expected_rc == 1 and "error:" not in run.stderr:
        return f"{example.label()}: no 'error:' line{tail}"
    missing = [p for p in example.written() if not (work / p).exists()]
    if missing:
        return f"{example.label()}: listed as written but absent: {missing}{tail}"
    differs = output_problem(example.output, run.output) if example.output else None
    if differs:
        return f"{example.label()}: {differs}"
    return None


class _Walkthrough:
    """The scratch checkout and how far through the pages it has been taken."""

    def __init__(self, work: Path, shared_run: Any) -> None:
        self.work = work
        self.shared_run = shared_run
        self.done: set[tuple[str, str]] = set()

    def run_section(self, section: tuple[str, str], capfd: pytest.CaptureFixture[str]) -> list[str]:
        problems: list[str] = []
        for example in EXAMPLES:
            if (example.page, example.section) == section:
                problem = _check(example, self.work, capfd, self.shared_run)
                if problem:
                    problems.append(problem)
        self.done.add(section)
        return problems


@pytest.fixture(scope="module")
def walkthrough(tmp_path_factory: pytest.TempPathFactory, shared_run: Any) -> _Walkthrough:
    shared_path()  # skips here, fails under CI, when the real data is absent
    root = tmp_path_factory.mktemp("readme") / "root"
    work = root / "main"
    work.mkdir(parents=True)
    (work / "sample_data").symlink_to(REPO / "sample_data", target_is_directory=True)
    (root / "shared").mkdir()
    (root / "shared" / "data").symlink_to(SHARED_DATA.resolve(), target_is_directory=True)
    return _Walkthrough(work, shared_run)


@pytest.mark.slow
@pytest.mark.parametrize("section", SECTIONS, ids=[_section_id(*s) for s in SECTIONS])
def test_page_section(
    section: tuple[str, str], walkthrough: _Walkthrough, capfd: pytest.CaptureFixture[str]
) -> None:
    """The section's examples run after every earlier section's, as a reader follows them."""
    for earlier in SECTIONS[: SECTIONS.index(section)]:
        if earlier not in walkthrough.done:
            problems = walkthrough.run_section(earlier, capfd)
            assert not problems, f"earlier section {earlier!r} failed:\n" + "\n\n".join(problems)
    problems = walkthrough.run_section(section, capfd)
    assert not problems, "\n\n".join(problems)
