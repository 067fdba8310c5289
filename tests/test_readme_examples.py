"""Every example in README.md and in docs/, run as one walkthrough, the way a new user follows them.

The examples are the ``slamcli …`` lines of ```sh blocks, the ``$ …`` lines of ```text blocks
(the lines after one are its shown output) and the ```python blocks. The pages are walked in the
order of ``ORDER``: README.md first, then the docs pages, each from top to bottom. They run in a
scratch checkout: ``root/main`` with ``sample_data`` linked to the repository's and
``root/shared/data`` linked to the real data, so ``sample_data/…`` and ``../shared/data/…``
resolve as in a fresh clone, and later examples find the files earlier ones wrote, across pages
(``runs/demo`` from docs/demo.md, ``runs/room`` from docs/dense.md, …).

An example passes when it exits with 0 (1 when the page shows it printing an ``error:``, 3 when
its line says ``# exit code 3``), prints no traceback, and the files it lists under ``Written``
exist. Output figures are not compared.

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
        return _Outcome(run.exit_code, run.stdout, run.stderr, run.traceback)
    capfd.readouterr()
    with _inside(work):
        result = CliRunner().invoke(app, args, env=ENV)
    helpers = capfd.readouterr()  # what helper processes wrote to the inherited descriptors
    if target is not None:
        (work / target).write_text(result.stdout, encoding="utf-8")
    trace = ""
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        assert result.exc_info is not None
        trace = "".join(traceback.format_exception(*result.exc_info))
    return _Outcome(result.exit_code, result.stdout, result.stderr + helpers.err, trace)


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
    return _Outcome(proc.returncode, proc.stdout, proc.stderr)


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
