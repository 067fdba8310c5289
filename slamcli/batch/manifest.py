"""Batch manifests: a TOML file listing ``slamcli run`` jobs, read into :class:`JobSpec` records.

Example::

    [defaults]                       # optional; any job key may be given here
    pipeline = "dense"
    fail_if = ["ate.rmse > 0.05"]

    [[job]]
    name = "visual-{stem}"           # {stem} is required when input is a glob
    input = "data/rgbd_*"            # relative to the manifest's folder; "~" is expanded
    pipeline = "visual"
    set = { max_features = 1500 }    # config overrides, as --set NAME=VALUE
    source = { robot = 2 }           # source options, as on the command line
    fail_if = ["ate.rmse > 0.03", "frames.lost > 0"]
    timeout_s = 600
    max_frames = 100
    map = false                      # also build the occupancy map
    mcap = false

A job's ``set`` and ``source`` tables are merged over the defaults' key by key; every other key,
``fail_if`` included, replaces the default. All problems are reported as :class:`ManifestError`
with the manifest's path and the line of the offending key (else of the job's ``[[job]]``).
"""

from __future__ import annotations

import re
import sys
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NoReturn

from slamcli.batch.gates import Gate, GateError, parse_gate
from slamcli.errors import FormatError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

JOB_KEYS = (
    "name",
    "input",
    "pipeline",
    "set",
    "source",
    "fail_if",
    "timeout_s",
    "max_frames",
    "map",
    "mcap",
)
"""The keys a ``[[job]]`` (and ``[defaults]``) may hold."""

RESERVED_NAMES = frozenset({"batch.json", "junit.xml", "report.html"})
"""Files a batch writes beside the job folders; no job may be named like them."""

_NAME_RE = re.compile(r"^[A-Za-z0-9._-]+$")
_GLOB_CHARS = re.compile(r"[*?\[]")
_TOML_POS = re.compile(r"(.*?)\s*\(at line (\d+), column (\d+)\)$")


class ManifestError(FormatError):
    """A batch manifest is malformed or names something that does not exist."""


@dataclass(frozen=True)
class JobSpec:
    """One job of a manifest, with defaults merged in and its input resolved.

    ``settings`` maps dotted config keys (nested TOML tables flattened: ``{dense = {a = 1}}``
    becomes ``"dense.a"``) to their TOML values, ready for ``--set NAME=VALUE``. ``source`` maps
    source option names, as written, to their values. ``line`` is the line of the job's
    ``[[job]]`` header.
    """

    name: str
    input: Path
    pipeline: str
    settings: dict[str, Any]
    source: dict[str, Any]
    fail_if: tuple[Gate, ...]
    timeout_s: float | None
    max_frames: int | None
    build_map: bool
    mcap: bool
    line: int
    key_lines: Mapping[str, int] = field(default_factory=dict, compare=False)
    """The line of each key the job sets itself (``set``, ``source``, ...)."""


@dataclass
class _Section:
    """Where one table (``[defaults]`` or one ``[[job]]``) sits in the raw text."""

    label: str
    header: int
    lines: list[tuple[int, str]]

    def key_line(self, key: str) -> int:
        """The line assigning ``key`` in this section, else the section's header line."""
        assign = re.compile(
            rf"""^\s*(?:{re.escape(key)}|"{re.escape(key)}"|'{re.escape(key)}')\s*[=.]"""
        )
        table = re.compile(rf"^\s*\[\s*(?:job|defaults)\s*\.\s*{re.escape(key)}\s*\]")
        for number, text in self.lines:
            if assign.match(text) or table.match(text):
                return number
        return self.header

    def value_line(self, key: str, value: str) -> int:
        """The line holding the string ``value`` of ``key`` (in a multi-line array)."""
        start = self.key_line(key)
        quoted = (f'"{value}"', f"'{value}'")
        for number, text in self.lines:
            if number >= start and any(q in text for q in quoted):
                return number
        return start


def _sections(text: str) -> tuple[_Section | None, list[_Section]]:
    """The ``[defaults]`` section and the ``[[job]]`` sections, in order, with their lines."""
    defaults: _Section | None = None
    jobs: list[_Section] = []
    current: _Section | None = None
    for number, line in enumerate(text.splitlines(), start=1):
        if re.match(r"^\s*\[\[\s*job\s*\]\]", line):
            current = _Section(f"job #{len(jobs) + 1}", number, [])
            jobs.append(current)
        elif re.match(r"^\s*\[\s*defaults\s*\]", line):
            current = defaults = _Section("[defaults]", number, [])
        elif re.match(r"^\s*\[\s*(?:job|defaults)\s*\.", line):
            if current is not None:
                current.lines.append((number, line))
        elif re.match(r"^\s*\[", line):
            current = None
        elif current is not None:
            current.lines.append((number, line))
    return defaults, jobs


class _Reader:
    """Validates one manifest; every error names the manifest and a line."""

    def __init__(
        self,
        path: Path,
        pipelines: Collection[str],
        check_metric: Callable[[str, str], bool] | None,
    ) -> None:
        self.path = path
        self.base = path.expanduser().absolute().parent
        self.pipelines = pipelines
        self.check_metric = check_metric

    def error(self, line: int | None, msg: str, hint: str | None = None) -> ManifestError:
        return ManifestError(self.path, msg, line=line, hint=hint)

    def read(self) -> list[JobSpec]:
        try:
            text = self.path.read_text(encoding="utf-8")
        except FileNotFoundError:
            raise self.error(None, "manifest not found") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise self.error(None, f"manifest cannot be read ({exc})") from exc
        try:
            doc = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            m = _TOML_POS.match(str(exc))
            line = int(m.group(2)) if m else None
            reason = f"{m.group(1)} at column {m.group(3)}" if m else str(exc)
            raise self.error(line, f"not valid TOML: {reason}") from exc
        defaults_section, job_sections = _sections(text)
        self.check_top_level(doc, text)
        defaults: dict[str, Any] = {}
        if "defaults" in doc:
            if defaults_section is None:
                defaults_section = _Section("[defaults]", _first_line(text, "defaults") or 1, [])
            defaults = self.check_table(doc["defaults"], defaults_section)
        raw_jobs = doc.get("job")
        if not raw_jobs:
            raise self.error(
                None,
                "no [[job]] entries",
                hint='add one: [[job]] name = "..." input = "..." pipeline = "..."',
            )
        if len(job_sections) != len(raw_jobs):
            raise self.error(
                _first_line(text, "job"),
                "jobs must be written as [[job]] tables",
                hint="write each job as a [[job]] header followed by its keys, "
                'not as "job = [...]"',
            )
        specs: list[JobSpec] = []
        seen: dict[str, tuple[str, int, Path]] = {}
        for raw, section in zip(raw_jobs, job_sections, strict=True):
            for spec in self.job(raw, section, defaults, defaults_section):
                folded = spec.name.lower()
                if folded in seen:
                    other, other_line, other_input = seen[folded]
                    case = "" if other == spec.name else f' (as "{other}": differs only in case)'
                    raise self.error(
                        section.key_line("name"),
                        f'duplicate job name "{spec.name}" (input {spec.input}): also used by '
                        f"the job at {self.path}:{other_line}{case} (input {other_input})",
                        hint="give each job its own name; with a glob input use {stem}",
                    )
                seen[folded] = (spec.name, section.key_line("name"), spec.input)
                specs.append(spec)
        return specs

    def check_top_level(self, doc: Mapping[str, Any], text: str) -> None:
        for key, value in doc.items():
            if key == "job" and isinstance(value, list):
                continue
            if key == "defaults" and isinstance(value, dict):
                continue
            line = _first_line(text, key)
            if key == "job":
                raise self.error(line, "jobs must be written as [[job]] (double brackets)")
            if key == "defaults":
                raise self.error(line, "defaults must be a table: [defaults]")
            raise self.error(
                line,
                f"unknown top-level key {key!r}",
                hint="a manifest holds an optional [defaults] table and [[job]] tables",
            )

    def check_table(self, raw: Mapping[str, Any], section: _Section) -> dict[str, Any]:
        """Type-check the keys of one job or of the defaults; returns them normalised."""
        name = raw.get("name")
        where = f'job "{name}"' if isinstance(name, str) else section.label
        out: dict[str, Any] = {}
        for key, value in raw.items():
            line = section.key_line(key)

            def bad(
                expected: str, key: str = key, value: Any = value, line: int = line
            ) -> NoReturn:
                raise self.error(line, f"{where}: {key} must be {expected}, not {_describe(value)}")

            if key not in JOB_KEYS:
                raise self.error(
                    line,
                    f"{where}: unknown key {key!r}",
                    hint=f"known keys: {', '.join(JOB_KEYS)}",
                )
            if key in ("name", "input", "pipeline"):
                if not isinstance(value, str) or not value.strip():
                    bad("a non-empty string")
                out[key] = value
            elif key == "set":
                if not isinstance(value, dict):
                    bad("a table, for example set = { max_features = 1500 }")
                out[key] = _flatten_settings(value)
            elif key == "source":
                if not isinstance(value, dict):
                    bad("a table, for example source = { robot = 2 }")
                nested = [k for k, v in value.items() if isinstance(v, dict)]
                if nested:
                    raise self.error(
                        line,
                        f"{where}: source.{nested[0]} must be a value, not a table",
                        hint="source options are flat: source = { robot = 2, max_dt = 0.05 }",
                    )
                out[key] = dict(value)
            elif key == "fail_if":
                if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
                    bad('a list of strings, for example fail_if = ["ate.rmse > 0.03"]')
                gates: list[Gate] = []
                for text in value:
                    try:
                        gates.append(parse_gate(text))
                    except GateError as exc:
                        raise self.error(
                            section.value_line(key, text), f"{where}: fail_if: {exc.msg}", exc.hint
                        ) from None
                out[key] = tuple(gates)
            elif key == "timeout_s":
                if (
                    isinstance(value, bool)
                    or not isinstance(value, (int, float))
                    or not value > 0
                    or value == float("inf")
                ):
                    bad("a positive number of seconds")
                out[key] = float(value)
            elif key == "max_frames":
                if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
                    bad("a positive integer")
                out[key] = value
            elif key in ("map", "mcap"):
                if not isinstance(value, bool):
                    bad("true or false")
                out[key] = value
        return out

    def job(
        self,
        raw: Mapping[str, Any],
        section: _Section,
        defaults: Mapping[str, Any],
        defaults_section: _Section | None,
    ) -> list[JobSpec]:
        own = self.check_table(raw, section)
        merged = {**defaults, **own}
        merged["set"] = {**defaults.get("set", {}), **own.get("set", {})}
        merged["source"] = {**defaults.get("source", {}), **own.get("source", {})}

        def origin(key: str) -> _Section:
            if key in own or defaults_section is None:
                return section
            return defaults_section

        for key in ("name", "input", "pipeline"):
            if key not in merged:
                label = f'job "{own["name"]}"' if "name" in own else section.label
                raise self.error(
                    section.header,
                    f"{label}: missing {key!r}",
                    hint="each [[job]] needs name, input and pipeline (pipeline may come from "
                    "[defaults])",
                )
        name_pattern: str = merged["name"]
        label = f'job "{name_pattern}"'
        pipeline: str = merged["pipeline"]
        if pipeline not in self.pipelines:
            raise self.error(
                origin("pipeline").key_line("pipeline"),
                f'{label}: unknown pipeline "{pipeline}"',
                hint=f"known pipelines: {', '.join(sorted(self.pipelines))}",
            )
        gates: tuple[Gate, ...] = merged.get("fail_if", ())
        if self.check_metric is not None:
            for gate in gates:
                if not self.check_metric(pipeline, gate.metric):
                    raise self.error(
                        origin("fail_if").value_line("fail_if", gate.text),
                        f'{label}: fail_if "{gate.text}": unknown metric "{gate.metric}" for '
                        f"the {pipeline} pipeline",
                        hint="gates name metrics as in run.json: ate.rmse, rpe.trans.rmse, "
                        "ms_per_frame, frames.lost, ...",
                    )
        name_line = origin("name").key_line("name")
        inputs = self.inputs(merged["input"], origin("input").key_line("input"), label)
        is_glob = bool(_GLOB_CHARS.search(merged["input"]))
        if is_glob and "{stem}" not in name_pattern:
            raise self.error(
                name_line,
                f'{label}: input "{merged["input"]}" is a glob, so the name must contain {{stem}}',
                hint=f'for example name = "{name_pattern}-{{stem}}"',
            )
        if not is_glob and "{stem}" in name_pattern:
            raise self.error(
                name_line,
                f"{label}: {{stem}} in a name needs a glob input (with * ? or [)",
            )
        specs = []
        for path in inputs:
            stem = path.name if path.is_dir() else path.stem
            name = name_pattern.replace("{stem}", stem) if is_glob else name_pattern
            self.check_name(name, name_line, label, path if is_glob else None)
            specs.append(
                JobSpec(
                    name=name,
                    input=path,
                    pipeline=pipeline,
                    settings=dict(merged["set"]),
                    source=dict(merged["source"]),
                    fail_if=gates,
                    timeout_s=merged.get("timeout_s"),
                    max_frames=merged.get("max_frames"),
                    build_map=merged.get("map", False),
                    mcap=merged.get("mcap", False),
                    line=section.header,
                    key_lines={key: section.key_line(key) for key in JOB_KEYS},
                )
            )
        return specs

    def inputs(self, pattern: str, line: int, label: str) -> list[Path]:
        """The paths an input names: the path itself, or a glob's matches (sorted)."""
        expanded = Path(pattern).expanduser()
        full = expanded if expanded.is_absolute() else self.base / expanded
        if _GLOB_CHARS.search(pattern):
            matches = _glob(full, pattern)
            if not matches:
                raise self.error(
                    line,
                    f'{label}: input glob "{pattern}" matches nothing (resolved against '
                    f"{self.base})",
                    hint="input paths are relative to the manifest's folder",
                )
            return matches
        # A missing input is the job's own failure (status "error" when it runs), not the
        # manifest's: the other jobs still run, as they would when a log disappears.
        return [full]

    def check_name(self, name: str, line: int, label: str, match: Path | None) -> None:
        from_match = f" (from {match})" if match is not None else ""
        if not _NAME_RE.match(name) or name in (".", ".."):
            raise self.error(
                line,
                f'{label}: name "{name}"{from_match} cannot be a folder name',
                hint="use letters, digits, '.', '_' and '-' only",
            )
        if name.lower() in RESERVED_NAMES:
            raise self.error(
                line,
                f'{label}: name "{name}" is reserved for the batch\'s own output',
                hint=f"avoid {', '.join(sorted(RESERVED_NAMES))}",
            )


def _glob(full: Path, written: str) -> list[Path]:
    """Sorted matches of the absolute pattern ``full``, spelt ``written`` in the manifest.

    Only parts the user wrote are read as wildcards, so a manifest folder or a home folder
    named like ``runs[1]`` is taken literally. Hidden entries match only when asked for.
    """
    wild = len(Path(written).parts) - (1 if written.startswith("~") else 0)
    parts = full.parts
    skip = len(parts) - wild
    first = next(i for i, part in enumerate(parts) if i >= skip and _GLOB_CHARS.search(part))
    anchor, rest = Path(*parts[:first]), Path(*parts[first:])
    hidden = rest.name.startswith(".")
    return sorted(p for p in anchor.glob(str(rest)) if hidden or not p.name.startswith("."))


def _first_line(text: str, key: str) -> int | None:
    """The first line that opens a table named ``key`` or assigns it at the top level."""
    pattern = re.compile(rf"^\s*(?:\[+\s*{re.escape(key)}\s*[\].]|{re.escape(key)}\s*[=.])")
    for number, row in enumerate(text.splitlines(), start=1):
        if pattern.match(row):
            return number
    return None


def _flatten_settings(table: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in table.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(_flatten_settings(value, f"{name}."))
        else:
            out[name] = value
    return out


def _describe(value: Any) -> str:
    kinds = {bool: "a boolean", str: "a string", int: "an integer", float: "a number"}
    kinds.update({list: "a list", dict: "a table"})
    kind = kinds.get(type(value), type(value).__name__)
    if isinstance(value, bool):
        shown = "true" if value else "false"
    else:
        shown = repr(value) if not isinstance(value, (list, dict)) else ""
    return f"{kind} {shown}".strip()


def load_manifest(
    path: str | Path,
    *,
    pipelines: Collection[str],
    check_metric: Callable[[str, str], bool] | None = None,
) -> list[JobSpec]:
    """Read and validate a batch manifest; one :class:`JobSpec` per job and per glob match.

    ``pipelines`` are the registered pipeline names; ``check_metric(pipeline, metric)``, when
    given, says whether a gate's metric exists for that pipeline. Raises :class:`ManifestError`.
    """
    return _Reader(Path(path), pipelines, check_metric).read()
