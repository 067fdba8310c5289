"""``fail_if`` gates: ``"ate.rmse > 0.03"`` fails a job when its run's metric is above 0.03.

A gate names a metric of ``run.json`` the way :func:`metric_value` resolves it, an operator and
either a number or a multiple of the same metric in a baseline run
(``"ms_per_frame > 1.2 * baseline"``). The condition is the failure condition. A gate whose
metric is missing, or whose baseline is missing, fails too: a gate that cannot be checked must
not pass silently.
"""

from __future__ import annotations

import math
import operator
import re
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from slamcli.errors import InputError

OPS: dict[str, Callable[[float, float], bool]] = {
    ">": operator.gt,
    ">=": operator.ge,
    "<": operator.lt,
    "<=": operator.le,
    "==": operator.eq,
    "!=": operator.ne,
}
"""The operators a gate may use."""

EXPECTED_FORM = '"<metric> <op> <number>" or "<metric> <op> <k> * baseline"'

_NUMBER = r"[+-]?(?:\d+(?:\.\d*)?|\.\d+)(?:[eE][+-]?\d+)?"
_METRIC = r"[A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z0-9_]+)*"
_GATE_RE = re.compile(
    rf"^\s*(?P<metric>{_METRIC})\s*(?P<op>>=|<=|==|!=|>|<)\s*"
    rf"(?:(?P<k>{_NUMBER})\s*\*\s*)?(?P<rhs>{_NUMBER}|baseline)\s*$"
)


class GateError(InputError):
    """A gate's text does not follow the gate syntax."""


@dataclass(frozen=True)
class Gate:
    """One parsed gate.

    ``threshold`` is the number a plain gate compares with; for a baseline gate it equals
    ``baseline_factor`` (the ``k`` in ``k * baseline``), and the limit is only known once a
    baseline run is given.
    """

    metric: str
    op: str
    threshold: float
    baseline_factor: float | None
    text: str

    @property
    def uses_baseline(self) -> bool:
        """True for ``"<metric> <op> <k> * baseline"`` gates."""
        return self.baseline_factor is not None


@dataclass(frozen=True)
class GateResult:
    """The outcome of one gate on one run; ``reason`` is a one-line explanation for people."""

    gate: str
    metric: str
    value: float | None
    limit: float | None
    baseline: float | None
    failed: bool
    reason: str


def parse_gate(text: str) -> Gate:
    """Parse ``"<metric> <op> <number>"`` or ``"<metric> <op> [<k> *] baseline"``."""
    m = _GATE_RE.match(text)
    if m is None or (m.group("k") is not None and m.group("rhs") != "baseline"):
        raise GateError(
            f'bad gate "{text}": expected {EXPECTED_FORM}',
            hint=f'operators: {" ".join(OPS)}; for example "ate.rmse > 0.03" or '
            '"ms_per_frame > 1.2 * baseline"',
        )
    op = m.group("op")
    if m.group("rhs") == "baseline":
        k = float(m.group("k")) if m.group("k") is not None else 1.0
        return Gate(m.group("metric"), op, k, k, text)
    return Gate(m.group("metric"), op, float(m.group("rhs")), None, text)


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _descend(table: Any, path: str) -> Any:
    node = table
    for part in path.split("."):
        if not isinstance(node, Mapping) or part not in node:
            return None
        node = node[part]
    return node


def metric_value(run_json: Mapping[str, Any], path: str) -> float | None:
    """The number a gate named ``path`` compares, or None when ``run.json`` has none.

    ``"ms_per_frame"`` alone means ``metrics.ms_per_frame.total``. Other names are looked up,
    by dotted descent, in ``metrics.evaluation``, then ``metrics``, then ``counts`` (where
    ``"frames.lost"`` and ``"frames_lost"`` both name ``counts["frames_lost"]``). A scope whose
    entry is not a number (a table, a list, a string, a boolean) does not stop the search.
    """
    metrics = run_json.get("metrics")
    metrics = metrics if isinstance(metrics, Mapping) else {}
    counts = run_json.get("counts")
    counts = counts if isinstance(counts, Mapping) else {}
    if path == "ms_per_frame":
        path = "ms_per_frame.total"
    candidates = (
        _descend(metrics.get("evaluation"), path),
        _descend(metrics, path),
        counts.get(path.replace(".", "_")),
        _descend(counts, path),
    )
    for value in candidates:
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
    return None


def _leaves(node: Any, prefix: str = "") -> Iterator[str]:
    if isinstance(node, Mapping):
        for key, value in node.items():
            if isinstance(key, str):
                yield from _leaves(value, f"{prefix}{key}" if not prefix else f"{prefix}.{key}")
    elif _is_number(node) and prefix:
        yield prefix


def flatten_metrics(run_json: Mapping[str, Any]) -> dict[str, float]:
    """Every numeric value of ``run.json`` under the names gates use for it.

    ``metrics.evaluation.*`` appear without the ``evaluation.`` prefix, other metrics by their
    dotted path, ``ms_per_frame`` as the total, counts by their key and with dots for
    underscores (``frames_lost`` and ``frames.lost``). Each value is what :func:`metric_value`
    gives for that name, so the table and the gates always agree.
    """
    metrics = run_json.get("metrics")
    metrics = metrics if isinstance(metrics, Mapping) else {}
    names: list[str] = list(_leaves(metrics.get("evaluation")))
    names += [n for n in _leaves(metrics) if not n.startswith("evaluation.")]
    if _is_number(_descend(metrics, "ms_per_frame.total")):
        names.append("ms_per_frame")
    for name in _leaves(run_json.get("counts")):
        names += [name, name.replace("_", ".")]
    out: dict[str, float] = {}
    for name in names:
        value = metric_value(run_json, name)
        if value is not None and name not in out:
            out[name] = value
    return out


def format_value(value: float | None) -> str:
    """A short, readable rendering of a metric value: 0.0312, 113.4, 30, 1.2e-05."""
    if value is None:
        return "—"
    if math.isnan(value) or math.isinf(value):
        return str(value)
    if value == int(value) and abs(value) < 1e15:
        return str(int(value))
    if abs(value) >= 1000:
        return f"{value:.1f}"
    if abs(value) >= 1e-4:
        return f"{value:.4g}"
    return f"{value:.3g}"


def _pair(a: float, b: float) -> tuple[str, str]:
    """Format two numbers so that unequal numbers never print the same."""
    fa, fb = format_value(a), format_value(b)
    if fa == fb and a != b:
        return repr(a), repr(b)
    return fa, fb


def _evaluate(gate: Gate, run_json: Mapping[str, Any], baseline_json: Any) -> GateResult:
    value = metric_value(run_json, gate.metric)
    baseline = metric_value(baseline_json, gate.metric) if baseline_json is not None else None

    def result(failed: bool, reason: str, limit: float | None = None) -> GateResult:
        return GateResult(gate.text, gate.metric, value, limit, baseline, failed, reason)

    if value is None:
        return result(True, f"{gate.metric} is missing from run.json")
    if math.isnan(value):
        return result(True, f"{gate.metric} is NaN")
    note = ""
    if gate.baseline_factor is not None:
        if baseline is None:
            why = "" if baseline_json is not None else " (no baseline run given)"
            return result(True, f"no baseline value for {gate.metric}{why}")
        limit = gate.baseline_factor * baseline
        note = f" ({format_value(gate.baseline_factor)} × baseline {format_value(baseline)})"
    else:
        limit = gate.threshold
    failed = OPS[gate.op](value, limit)
    shown_value, shown_limit = _pair(value, limit)
    if failed:
        return result(True, f"{gate.metric} = {shown_value} {gate.op} {shown_limit}{note}", limit)
    return result(False, f"{gate.metric} = {shown_value}, not {gate.op} {shown_limit}{note}", limit)


def evaluate_gates(
    gates: Sequence[Gate],
    run_json: Mapping[str, Any],
    baseline_json: Mapping[str, Any] | None = None,
) -> list[GateResult]:
    """Check each gate against ``run_json`` (and ``baseline_json`` for baseline gates).

    A result is ``failed`` when the gate's condition holds, when the metric is missing or NaN,
    or when a baseline gate has no baseline value.
    """
    return [_evaluate(gate, run_json, baseline_json) for gate in gates]
