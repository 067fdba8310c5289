"""Every example in README.md runs, in README order, the way a new user follows it.

The examples are the ``slamcli …`` lines of ```sh blocks, the ``$ …`` lines of ```text blocks
(the lines after one are its shown output) and the ```python blocks. They run in a scratch
checkout: ``root/main`` with ``sample_data`` linked to the repository's and ``root/shared/data``
linked to the real data, so ``sample_data/…`` and ``../shared/data/…`` resolve as in a fresh
clone, and later examples find the files earlier ones wrote (``runs/demo``, ``room.mcap``, …).

An example passes when it exits with 0 (1 when the README shows it printing an ``error:``, 3 when
its line says ``# exit code 3``), prints no traceback, and the files it lists under ``Written``
exist. Output figures are not compared.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from conftest import SHARED_DATA, shared_path

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"

# Each example may take a while (a dense run over the 150-frame TUM excerpt takes ~40 s), but
# none should take minutes.
TIMEOUT_S = 300
MIN_EXAMPLES = 20

_FENCE = re.compile(r"^```(\w*)\s*$")
_HEADING = re.compile(r"^#{1,6}\s+(.*?)\s*$")
_EXIT_CODE = re.compile(r"#.*\bexit code (\d)\b")
_WRITTEN = re.compile(r"^\s*\d+ bytes\s+(\S+)\s*$")


@dataclass
class Example:
    """One README example: a command line (or a Python script) and what the README shows."""

    section: str
    line: int
    kind: str  # "slamcli", "shell" or "python"
    text: str
    output: list[str] = field(default_factory=list)
    expected_rc: int = 0

    def label(self) -> str:
        first = self.text.splitlines()[0] if self.text else ""
        return f"README.md:{self.line} ({self.section}): {first}"

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


def parse_readme(text: str) -> list[Example]:
    """The README's examples in document order."""
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
            examples.append(Example(section, start + 1, "python", "\n".join(body) + "\n"))
        elif lang == "sh":
            j = 0
            while j < len(body):
                command, nxt = _joined(body, j)
                if command.startswith("slamcli "):
                    rc = _EXIT_CODE.search(command)
                    examples.append(
                        Example(
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
                examples.append(Example(section, start + j + 1, kind, command, output, expected))
                j = out_end
        i = end + 1
    return examples


EXAMPLES = parse_readme(README.read_text(encoding="utf-8"))
SECTIONS = list(dict.fromkeys(e.section for e in EXAMPLES))


def _section_id(section: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "-", section).strip("-").lower()


def test_readme_examples_are_found() -> None:
    """The extraction finds every kind of example; a README reshuffle cannot silently drop them."""
    assert len(EXAMPLES) >= MIN_EXAMPLES, [e.label() for e in EXAMPLES]
    kinds = {e.kind for e in EXAMPLES}
    assert {"slamcli", "python"} <= kinds
    assert any(e.written() for e in EXAMPLES)
    assert any(e.expected_rc == 1 for e in EXAMPLES)


def _argv(command: str) -> tuple[list[str], str | None]:
    """The argv of a ``slamcli`` line (comments stripped) and the file a ``>`` sends stdout to."""
    tokens = shlex.split(command, comments=True)
    target = None
    if ">" in tokens:
        at = tokens.index(">")
        if at != len(tokens) - 2:
            raise ValueError(f"only 'slamcli … > FILE' redirection is supported: {command}")
        target = tokens[at + 1]
        tokens = tokens[:at]
    assert tokens[0] == "slamcli"
    return [sys.executable, "-m", "slamcli", *tokens[1:]], target


def _run(example: Example, work: Path) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, NO_COLOR="1", MPLBACKEND="Agg", COLUMNS="100")
    kwargs = dict(cwd=work, env=env, capture_output=True, text=True, timeout=TIMEOUT_S)
    if example.kind == "python":
        script = work / f"readme_example_{example.line}.py"
        script.write_text(example.text, encoding="utf-8")
        return subprocess.run([sys.executable, script.name], check=False, **kwargs)
    if example.kind == "shell":
        return subprocess.run(["bash", "-c", example.text], check=False, **kwargs)
    argv, target = _argv(example.text)
    proc = subprocess.run(argv, check=False, **kwargs)
    if target is not None:
        (work / target).write_text(proc.stdout, encoding="utf-8")
    return proc


def _check(example: Example, work: Path) -> str | None:
    """What is wrong with the example's run, or None."""
    proc = _run(example, work)
    tail = f"\n--- stdout ---\n{proc.stdout[-3000:]}\n--- stderr ---\n{proc.stderr[-3000:]}"
    if "Traceback" in proc.stderr:
        return f"{example.label()}: traceback{tail}"
    if proc.returncode != example.expected_rc:
        return (
            f"{example.label()}: exit code {proc.returncode}, "
            f"README expects {example.expected_rc}{tail}"
        )
    if example.expected_rc == 1 and "error:" not in proc.stderr:
        return f"{example.label()}: no 'error:' line{tail}"
    missing = [p for p in example.written() if not (work / p).exists()]
    if missing:
        return f"{example.label()}: listed as written but absent: {missing}{tail}"
    return None


class _Walkthrough:
    """The scratch checkout and how far through the README it has been taken."""

    def __init__(self, work: Path) -> None:
        self.work = work
        self.done: set[str] = set()

    def run_section(self, section: str) -> list[str]:
        problems: list[str] = []
        for example in EXAMPLES:
            if example.section == section:
                problem = _check(example, self.work)
                if problem:
                    problems.append(problem)
        self.done.add(section)
        return problems


@pytest.fixture(scope="module")
def walkthrough(tmp_path_factory: pytest.TempPathFactory) -> _Walkthrough:
    shared_path()  # skips here, fails under CI, when the real data is absent
    root = tmp_path_factory.mktemp("readme") / "root"
    work = root / "main"
    work.mkdir(parents=True)
    (work / "sample_data").symlink_to(REPO / "sample_data", target_is_directory=True)
    (root / "shared").mkdir()
    (root / "shared" / "data").symlink_to(SHARED_DATA.resolve(), target_is_directory=True)
    return _Walkthrough(work)


@pytest.mark.slow
@pytest.mark.parametrize("section", SECTIONS, ids=[_section_id(s) for s in SECTIONS])
def test_readme_section(section: str, walkthrough: _Walkthrough) -> None:
    """The section's examples run after every earlier section's, as a reader follows them."""
    for earlier in SECTIONS[: SECTIONS.index(section)]:
        if earlier not in walkthrough.done:
            problems = walkthrough.run_section(earlier)
            assert not problems, f"earlier section {earlier!r} failed:\n" + "\n\n".join(problems)
    problems = walkthrough.run_section(section)
    assert not problems, "\n\n".join(problems)
