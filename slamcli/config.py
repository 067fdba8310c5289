"""Configuration: frozen dataclass sections, TOML files and ``--set key=value`` overrides.

Every configurable part (each pipeline) declares its settings as a frozen dataclass, one
*section*. Its defaults are the code's defaults; a TOML file's ``[section]`` table overrides
them, and ``--set`` strings override the file::

    # dense.toml
    [dense]
    voxel_size_m = 0.02
    odometry_iterations = [10, 5, 3]

    load_config(DenseConfig, "dense", Path("dense.toml"), ["dense.depth_max_m=3.5"])

Field types that can be configured: ``bool``, ``int``, ``float`` (a TOML integer is accepted
and converted), ``str``, ``Literal[...]`` choices, ``tuple[T, ...]`` and fixed-length
``tuple[T1, T2]`` of those scalars (TOML arrays), and ``T | None`` (``None`` cannot be written in
TOML: such a field keeps its default unless given a value).

A field declares its help text and allowed range in its metadata, most easily with
:func:`setting`::

    @dataclass(frozen=True)
    class DenseConfig:
        voxel_size_m: float = setting(0.01, help="TSDF voxel edge", unit="m", gt=0.0, max=0.5)
        method: str = setting("hybrid", help="odometry loss", choices=("hybrid", "intensity"))
        iterations: tuple[int, ...] = setting((6, 4, 2), help="per pyramid level", min=1)

Metadata keys (all optional; ``dataclasses.field(default=..., metadata={...})`` works too):
``help`` (one line, written as a comment by :func:`dump_config`; without it the field's entry
in a Google-style ``Attributes:`` section of the class docstring is used), ``unit``,
``min`` / ``max`` (inclusive bounds), ``gt`` / ``lt`` (exclusive bounds) and ``choices`` (the
allowed values). Bounds apply to every element of a tuple. A value outside them raises
:class:`~slamcli.errors.ConfigError` naming the dotted key, the value and the allowed range.
Settings made in code (a command's options) are checked against the same metadata by
:func:`check_settings`, which names each field as the caller says (its option).
"""

from __future__ import annotations

import dataclasses
import difflib
import inspect
import json
import math
import re
import sys
import textwrap
import types
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal, TypeVar, Union, get_args, get_origin

from slamcli.errors import ConfigError, FormatError, InputError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on Python 3.10 only
    import tomli as tomllib

T = TypeVar("T")

_COMMENT_WIDTH = 98


def setting(
    default: T,
    *,
    help: str = "",
    unit: str | None = None,
    min: float | None = None,
    max: float | None = None,
    gt: float | None = None,
    lt: float | None = None,
    choices: Sequence[Any] | None = None,
) -> T:
    """A dataclass field with a default, help text and an allowed range in its metadata.

    Args:
        default: the default value (immutable: use tuples, not lists).
        help: one line describing the setting; :func:`dump_config` writes it as a comment.
        unit: unit of the value (``"m"``, ``"deg"``, ...), shown with the help text.
        min, max: inclusive bounds of a number (of each element of a tuple).
        gt, lt: exclusive bounds of a number (of each element of a tuple).
        choices: the only values allowed.
    """
    meta: dict[str, Any] = {"help": help}
    for key, value in (("unit", unit), ("min", min), ("max", max), ("gt", gt), ("lt", lt)):
        if value is not None:
            meta[key] = value
    if choices is not None:
        meta["choices"] = tuple(choices)
    return dataclasses.field(default=default, metadata=meta)


def load_config(
    section_cls: type[T],
    section_name: str,
    file: str | Path | None = None,
    sets: Sequence[str] = (),
) -> T:
    """Build a config section: defaults, then the file's ``[section_name]`` table, then ``sets``.

    Args:
        section_cls: a dataclass type whose fields all have defaults.
        section_name: the TOML table (and ``--set`` prefix) of this section, e.g. ``"dense"``.
        file: a TOML file; tables other than ``[section_name]`` are ignored (one file can hold
            the sections of several pipelines).
        sets: ``"key=value"`` or ``"section.key=value"`` overrides; the value is read as a TOML
            value (``0.01``, ``true``, ``[10, 5, 3]``, ``"text"``; text for a string setting may
            be unquoted).

    Raises:
        InputError: the file is missing or unreadable.
        FormatError: the file is not valid TOML (names the line).
        ConfigError: an unknown key, a value of the wrong type or outside its range, or a
            malformed ``--set``; the message names the dotted key.
    """
    fields = _fields(section_cls)
    values: dict[str, Any] = {}
    if file is not None:
        table = _read_section(Path(file), section_name)
        for key, raw in table.items():
            where = f"{file}: {section_name}.{key}"
            values[key] = _check(fields, section_name, key, raw, where)
    for text in sets:
        key, raw = _parse_set(text, section_name, fields)
        values[key] = _check(fields, section_name, key, raw, f"--set {section_name}.{key}")
    return section_cls(**values)


def dump_config(instance: Any, section_name: str) -> str:
    """The section as a TOML document; :func:`load_config` of it gives an equal instance.

    Each field is preceded by a comment holding its help text, unit and allowed range when the
    field declares them; a field whose value is ``None`` is written commented out.
    """
    if not dataclasses.is_dataclass(instance) or isinstance(instance, type):
        raise TypeError(f"dump_config needs a dataclass instance, got {type(instance).__name__}")
    lines: list[str] = []
    doc = inspect.cleandoc(type(instance).__doc__ or "")
    if doc:
        lines.append("# " + _plain(doc.splitlines()[0]))
    lines.append(f"[{section_name}]")
    attribute_docs = _class_attribute_docs(type(instance))
    for f in dataclasses.fields(instance):
        if not f.init:
            continue
        comment = _describe(f, attribute_docs.get(f.name, ""))
        if comment:
            lines.extend(f"# {part}" for part in textwrap.wrap(comment, width=_COMMENT_WIDTH))
        value = getattr(instance, f.name)
        if value is None:
            lines.append(f"# {f.name} = (unset)")
        else:
            lines.append(f"{f.name} = {_toml_value(value)}")
    return "\n".join(lines) + "\n"


def check_settings(instance: T, names: Mapping[str, str] | None = None) -> T:
    """``instance`` itself once every field's value has the field's type and lies in its range.

    :func:`load_config` checks what it reads; this checks settings made in code, such as a
    command's options passed straight to a dataclass. A ``None`` in a ``T | None`` field is
    accepted.

    Args:
        instance: a dataclass instance whose fields declare their ranges (:func:`setting`).
        names: what the message calls a field, e.g. ``{"resolution_m": "--resolution"}`` for
            the command-line option that sets it; other fields go by their field name.

    Raises:
        ConfigError: ``"--resolution: expected a number > 0 (m), got 0"``, with the field's
            help text (else its entry in the class docstring's ``Attributes:``) as the hint.
    """
    if not dataclasses.is_dataclass(instance) or isinstance(instance, type):
        raise TypeError(f"check_settings needs a dataclass instance, got {type(instance).__name__}")
    names = names or {}
    docs = _class_attribute_docs(type(instance))
    for name, (f, tp) in _fields(type(instance)).items():
        value = getattr(instance, name)
        if value is None and _is_optional(tp):
            continue
        # Tuple settings arrive from TOML as lists, the form the converter checks.
        raw = list(value) if isinstance(value, tuple) else value
        hint = f.metadata.get("help") or docs.get(name) or None
        _checked_value(f, tp, raw, names.get(name, name), hint)
    return instance


def _class_attribute_docs(cls: type[Any]) -> dict[str, str]:
    """Help text per field from the ``Attributes:`` sections of ``cls`` and its bases (fields
    inherited from a shared base class are documented in the base's docstring)."""
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        docs.update(_attribute_docs(inspect.cleandoc(klass.__doc__ or "")))
    return docs


def _fields(section_cls: type[Any]) -> dict[str, tuple[dataclasses.Field[Any], Any]]:
    """Init fields of a dataclass by name, each with its resolved type annotation."""
    if not dataclasses.is_dataclass(section_cls):
        raise TypeError(f"{section_cls!r} is not a dataclass")
    hints = typing.get_type_hints(section_cls)
    return {f.name: (f, hints[f.name]) for f in dataclasses.fields(section_cls) if f.init}


def _read_section(path: Path, section_name: str) -> dict[str, Any]:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise InputError(f"{path}: config file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: config file cannot be read ({exc})") from exc
    try:
        doc = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        # tomllib puts the position in the message: "Invalid value (at line 3, column 11)".
        m = re.match(r"(.*?)\s*\(at line (\d+), column (\d+)\)$", str(exc))
        line = int(m.group(2)) if m else None
        reason = f"{m.group(1)} at column {m.group(3)}" if m else str(exc)
        raise FormatError(
            path, f"not valid TOML: {reason}", line=line, hint=_dump_hint(section_name)
        ) from exc
    stray = [k for k, v in doc.items() if not isinstance(v, dict)]
    if stray:
        raise ConfigError(
            f"{path}: key {stray[0]!r} is outside any [section]",
            hint=f"put it under [{section_name}]; {_dump_hint(section_name)}",
        )
    table = doc.get(section_name, {})
    return dict(table)


def _parse_set(
    text: str, section_name: str, fields: Mapping[str, tuple[dataclasses.Field[Any], Any]]
) -> tuple[str, Any]:
    """``"[section.]key=value"`` -> (key, parsed value)."""
    key, sep, value_text = text.partition("=")
    key = key.strip()
    value_text = value_text.strip()
    if not sep or not key:
        raise ConfigError(
            f"--set {text!r}: expected KEY=VALUE",
            hint=f"for example --set {section_name}.{next(iter(fields), 'key')}=VALUE",
        )
    section, dot, name = key.rpartition(".")
    if dot and section != section_name:
        raise ConfigError(
            f"--set {key}: section {section!r} does not apply here; this command reads "
            f"[{section_name}]",
            hint=f"write --set {section_name}.{name}=... or --set {name}=...",
        )
    if not value_text:
        raise ConfigError(
            f"--set {section_name}.{name}: no value after '='",
            hint=f"for example --set {section_name}.{name}=VALUE",
        )
    if name not in fields:
        _unknown_key(fields, section_name, name, f"--set {section_name}.{name}")
    try:
        value = tomllib.loads(f"v = {value_text}")["v"]
    except tomllib.TOMLDecodeError:
        value = value_text
        if not _accepts_text(fields[name][1]):
            raise ConfigError(
                f"--set {section_name}.{name}={value_text}: not a TOML value; expected "
                f"{_expected(fields[name][0], fields[name][1])}",
                hint="numbers as 0.5 or 10, booleans as true/false, lists as [10, 5, 3]",
            ) from None
    return name, value


def _accepts_text(tp: Any) -> bool:
    """Whether a setting of type ``tp`` takes a string (so unquoted text means itself)."""
    if tp is str:
        return True
    if get_origin(tp) is Literal:
        return all(isinstance(a, str) for a in get_args(tp))
    if _is_optional(tp):
        return _accepts_text(_strip_optional(tp))
    return False


def _unknown_key(
    fields: Mapping[str, Any], section_name: str, key: str, where: str
) -> typing.NoReturn:
    close = difflib.get_close_matches(key, list(fields), n=1)
    hint = f"did you mean {section_name}.{close[0]}? " if close else ""
    raise ConfigError(
        f"{where}: unknown setting; [{section_name}] has {', '.join(fields)}",
        hint=hint + _dump_hint(section_name),
    )


def _dump_hint(section_name: str) -> str:
    return f"'slamcli config dump {section_name}' prints every setting with its default"


def _check(
    fields: Mapping[str, tuple[dataclasses.Field[Any], Any]],
    section_name: str,
    key: str,
    raw: Any,
    where: str,
) -> Any:
    """The value for ``fields[key]`` converted to its type, or a ConfigError naming ``where``."""
    if key not in fields:
        _unknown_key(fields, section_name, key, where)
    f, tp = fields[key]
    return _checked_value(f, tp, raw, where, f.metadata.get("help") or _dump_hint(section_name))


def _checked_value(
    f: dataclasses.Field[Any], tp: Any, raw: Any, where: str, hint: str | None
) -> Any:
    """``raw`` converted to type ``tp`` when it lies in ``f``'s range, else a ConfigError
    naming ``where``."""
    value = _convert(tp, raw)
    if value is _BAD or not _in_range(f.metadata, value):
        raise ConfigError(
            f"{where}: expected {_expected(f, tp)}, got {_toml_value(raw)}", hint=hint
        )
    return value


class _Bad:
    """Marker for a value that does not fit its type."""


_BAD: Any = _Bad()


def _is_optional(tp: Any) -> bool:
    return get_origin(tp) in (Union, types.UnionType) and type(None) in get_args(tp)


def _strip_optional(tp: Any) -> Any:
    rest = [a for a in get_args(tp) if a is not type(None)]
    return rest[0] if len(rest) == 1 else Union[tuple(rest)]  # noqa: UP007


def _convert(tp: Any, raw: Any) -> Any:
    """``raw`` (as TOML parsed it) converted to type ``tp``, or ``_BAD``."""
    if _is_optional(tp):
        return _convert(_strip_optional(tp), raw)
    origin = get_origin(tp)
    if origin is Literal:
        return raw if any(raw == a and type(raw) is type(a) for a in get_args(tp)) else _BAD
    if origin is tuple:
        args = get_args(tp)
        if not isinstance(raw, list):
            return _BAD
        if len(args) == 2 and args[1] is Ellipsis:
            items = [_convert(args[0], r) for r in raw]
        elif len(args) == len(raw):
            items = [_convert(a, r) for a, r in zip(args, raw, strict=True)]
        else:
            return _BAD
        return _BAD if any(i is _BAD for i in items) else tuple(items)
    if tp is bool:
        return raw if isinstance(raw, bool) else _BAD
    if tp is int:
        return raw if isinstance(raw, int) and not isinstance(raw, bool) else _BAD
    if tp is float:
        if isinstance(raw, (int, float)) and not isinstance(raw, bool) and math.isfinite(raw):
            return float(raw)
        return _BAD
    if tp is str:
        return raw if isinstance(raw, str) else _BAD
    raise TypeError(f"config fields of type {tp!r} are not supported")


def _in_range(meta: Mapping[str, Any], value: Any) -> bool:
    choices = meta.get("choices")
    if choices is not None and value not in choices:
        return False
    for v in value if isinstance(value, tuple) else (value,):
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            continue
        if "min" in meta and v < meta["min"]:
            return False
        if "max" in meta and v > meta["max"]:
            return False
        if "gt" in meta and v <= meta["gt"]:
            return False
        if "lt" in meta and v >= meta["lt"]:
            return False
    return True


_PLURAL = {bool: "booleans", int: "integers", float: "numbers", str: "strings"}


def _type_name(tp: Any) -> str:
    if _is_optional(tp):
        return _type_name(_strip_optional(tp))
    origin = get_origin(tp)
    if origin is Literal:
        return "one of " + ", ".join(_toml_value(a) for a in get_args(tp))
    if origin is tuple:
        args = get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return f"a list of {_PLURAL.get(args[0], _type_name(args[0]))}"
        return f"a list of {len(args)} values ({', '.join(_type_name(a) for a in args)})"
    return {bool: "true or false", int: "an integer", float: "a number", str: "a string"}.get(
        tp, getattr(tp, "__name__", str(tp))
    )


def _range_text(meta: Mapping[str, Any]) -> str:
    if meta.get("choices") is not None:
        return "one of " + ", ".join(_toml_value(c) for c in meta["choices"])
    # Integers print in full: ``:g`` would show a bound such as 2**31 - 1 as 2.14748e+09.
    b = {k: str(v) if isinstance(v, int) else f"{v:g}" for k, v in meta.items() if k in _BOUNDS}
    low = f"[{b['min']}" if "min" in b else f"({b['gt']}" if "gt" in b else ""
    high = f"{b['max']}]" if "max" in b else f"{b['lt']})" if "lt" in b else ""
    if low and high:
        return f"in {low}, {high}"
    if low:
        return f">= {b['min']}" if "min" in b else f"> {b['gt']}"
    if high:
        return f"<= {b['max']}" if "max" in b else f"< {b['lt']}"
    return ""


_BOUNDS = ("min", "max", "gt", "lt")


def _expected(f: dataclasses.Field[Any], tp: Any) -> str:
    """``"a number in (0, 0.5] (m)"``: the type, range and unit a field accepts."""
    meta = f.metadata
    rng = _range_text(meta)
    text = rng
    if meta.get("choices") is None:
        text = _type_name(tp) + (f" {rng}" if rng else "")
    return text + (f" ({meta['unit']})" if meta.get("unit") else "")


def _describe(f: dataclasses.Field[Any], doc: str = "") -> str:
    """The comment line for a field: help text (else ``doc``), then unit and range."""
    meta = f.metadata
    parts = [(meta.get("help") or doc).strip()]
    rng = _range_text(meta)
    extra = ", ".join(p for p in (meta.get("unit"), rng) if p)
    if extra:
        parts.append(f"({extra})")
    return " ".join(p for p in parts if p)


def _plain(text: str) -> str:
    """Docstring text without reST roles and literals: ``:class:`X``` -> ``X``."""
    text = re.sub(r":\w+:`~?([^`]+)`", r"\1", text)
    return text.replace("``", "")


def _attribute_docs(doc: str) -> dict[str, str]:
    """Help text per field from a Google-style ``Attributes:`` section of a class docstring.

    An entry ``name: text`` may continue on more deeply indented lines; ``a, b: text``
    describes both ``a`` and ``b``.
    """
    out: dict[str, str] = {}
    lines = doc.splitlines()
    try:
        start = next(i for i, ln in enumerate(lines) if ln.strip() == "Attributes:")
    except StopIteration:
        return out
    base = len(lines[start]) - len(lines[start].lstrip())
    entry_indent: int | None = None
    names: list[str] = []
    for ln in lines[start + 1 :]:
        if not ln.strip():
            continue
        indent = len(ln) - len(ln.lstrip())
        if indent <= base:
            break
        m = re.match(r"\s*([\w]+(?:\s*,\s*\w+)*)\s*:\s*(.*)$", ln)
        if m and (entry_indent is None or indent == entry_indent):
            entry_indent = indent
            names = [n.strip() for n in m.group(1).split(",")]
            for n in names:
                out[n] = m.group(2).strip()
        else:
            for n in names:
                out[n] = f"{out[n]} {ln.strip()}".strip()
    return {k: _plain(v) for k, v in out.items()}


def _toml_value(value: Any) -> str:
    """A TOML literal for a bool, int, float, str, or a list/tuple of those."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        # JSON escapes the control characters TOML forbids in strings, except DEL.
        return json.dumps(value, ensure_ascii=False).replace("\x7f", "\\u007f")
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + "}"
    return json.dumps(str(value))


__all__ = ["check_settings", "dump_config", "load_config", "setting"]
