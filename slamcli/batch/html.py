"""The batch report: one self-contained HTML file (inline CSS, images as data: URIs).

It opens from a CI artefact or an e-mail attachment with no network and no folder beside it,
and the same inputs always give the same bytes.
"""

from __future__ import annotations

import base64
import html
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from slamcli.atomic import write_text_atomic
from slamcli.batch.gates import GateResult, format_value

STATUS_LABELS = {
    "passed": "passed",
    "gate_failed": "gate failed",
    "data_lost": "data lost",
    "error": "error",
}
"""The statuses counted in the header, in display order, with their labels."""

_LOWER_IS_BETTER = {"ate", "rpe", "rmse", "error", "lost", "skipped"}

_CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; margin: 1.5rem;
       color: #1d2430; background: #fff; }
h1 { margin-bottom: 0.2rem; }
.meta { color: #5a6473; margin-top: 0; }
.counts span { display: inline-block; margin-right: 0.6rem; }
table { border-collapse: collapse; margin: 0.8rem 0; }
th, td { border: 1px solid #d5dae1; padding: 0.3rem 0.5rem; text-align: left;
         vertical-align: top; }
th { background: #f2f4f7; }
.num { text-align: right; font-variant-numeric: tabular-nums; }
.badge { display: inline-block; padding: 0.1rem 0.5rem; border-radius: 0.6rem;
         color: #fff; font-weight: 600; font-size: 0.9em; white-space: nowrap; }
.status-passed { background: #1f883d; }
.status-gate_failed { background: #cf222e; }
.status-data_lost { background: #bc4c00; }
.status-error { background: #6e40c9; }
.status-other { background: #57606a; }
.pass { color: #1f883d; }
.fail { color: #cf222e; }
.better { color: #1f883d; }
.worse { color: #cf222e; }
.neutral { color: #57606a; }
.error { color: #8250df; }
ul.plain { list-style: none; margin: 0; padding: 0; }
pre { background: #f6f8fa; padding: 0.6rem; overflow-x: auto; white-space: pre-wrap; }
img { max-width: 100%; height: auto; border: 1px solid #d5dae1; }
section.job { border-top: 2px solid #d5dae1; margin-top: 1.5rem; }
"""


@dataclass
class ReportRow:
    """One job as the report shows it.

    ``changes`` maps a metric to (baseline value, value now); ``run_link`` is a link relative
    to the report, such as ``"visual-rpy/"``; ``report_png`` is embedded when it can be read.
    """

    name: str
    pipeline: str
    input: str
    status: str
    wall_s: float
    gates: Sequence[GateResult] = field(default_factory=list)
    metrics: Mapping[str, float] = field(default_factory=dict)
    changes: Mapping[str, tuple[float | None, float | None]] = field(default_factory=dict)
    run_link: str = ""
    report_png: Path | None = None
    error: str = ""


def _e(text: object) -> str:
    return html.escape(str(text), quote=True)


def lower_is_better(metric: str) -> bool:
    """Whether a smaller value of ``metric`` is an improvement (errors, timings, losses)."""
    if metric.startswith("ms_per_frame"):
        return True
    tokens = set(re.split(r"[._]", metric))
    return bool(tokens & _LOWER_IS_BETTER)


def format_change(metric: str, baseline: float | None, now: float | None) -> tuple[str, str]:
    """``("0.0312 (−4.1 %)", css class)`` for a metric's value now against its baseline.

    The class is ``better``/``worse`` for metrics where lower is better, else ``neutral``.
    """
    if now is None:
        return (f"missing (baseline {format_value(baseline)})", "worse")
    if baseline is None:
        return (f"{format_value(now)} (new)", "neutral")
    delta = now - baseline
    if delta == 0:
        return (f"{format_value(now)} (±0 %)", "neutral")
    sign = "+" if delta > 0 else "\u2212"
    if baseline != 0:
        change = f"{sign}{abs(delta) / abs(baseline) * 100:.1f} %"
    else:
        change = f"{sign}{format_value(abs(delta))}, baseline 0"
    css = "neutral"
    if lower_is_better(metric):
        css = "better" if delta < 0 else "worse"
    return (f"{format_value(now)} ({change})", css)


def _badge(status: str) -> str:
    css = f"status-{status}" if status in STATUS_LABELS else "status-other"
    return f'<span class="badge {css}">{_e(STATUS_LABELS.get(status, status))}</span>'


def _duration(seconds: float) -> str:
    if seconds < 60:
        return f"{seconds:.1f} s"
    minutes, secs = divmod(round(seconds), 60)
    return f"{minutes} min {secs:02d} s"


def _gate_item(g: GateResult) -> str:
    mark = '<span class="fail">✗</span>' if g.failed else '<span class="pass">✓</span>'
    return f"<li>{mark} <code>{_e(g.gate)}</code>: {_e(g.reason)}</li>"


def _change_item(metric: str, baseline: float | None, now: float | None) -> str:
    text, css = format_change(metric, baseline, now)
    return f'<li>{_e(metric)} <span class="{css}">{_e(text)}</span></li>'


def _image(png: Path, name: str) -> str:
    try:
        data = png.read_bytes()
    except OSError as exc:
        return f'<p class="neutral">report image not available: {_e(png)} ({_e(exc.strerror)})</p>'
    if data.startswith(b"\x89PNG\r\n\x1a\n"):
        mime = "image/png"
    elif data.startswith(b"\xff\xd8\xff"):
        mime = "image/jpeg"
    else:
        return f'<p class="neutral">report image not available: {_e(png)} is not a PNG</p>'
    encoded = base64.b64encode(data).decode("ascii")
    return f'<img src="data:{mime};base64,{encoded}" alt="report of {_e(name)}">'


def _summary(rows: Sequence[ReportRow], show_changes: bool) -> list[str]:
    head = ["Job", "Pipeline", "Status", "Gates", "Key metrics"]
    if show_changes:
        head.append("Change against baseline")
    head += ["Wall time", "Run"]
    out = ["<table>", "<tr>" + "".join(f"<th>{h}</th>" for h in head) + "</tr>"]
    for i, row in enumerate(rows, start=1):
        gates = "".join(_gate_item(g) for g in row.gates) or "<li>none</li>"
        if row.status == "error" and row.error:
            gates = f'<li class="error">{_e(row.error.splitlines()[0])}</li>'
        metrics = "".join(f"<li>{_e(k)} {_e(format_value(v))}</li>" for k, v in row.metrics.items())
        cells = [
            f'<a href="#job-{i}">{_e(row.name)}</a>',
            _e(row.pipeline),
            _badge(row.status),
            f'<ul class="plain">{gates}</ul>',
            f'<ul class="plain">{metrics}</ul>',
        ]
        if show_changes:
            items = "".join(_change_item(k, b, n) for k, (b, n) in row.changes.items())
            cells.append(f'<ul class="plain">{items}</ul>')
        cells.append(f'<span class="num">{_e(_duration(row.wall_s))}</span>')
        cells.append(f'<a href="{_e(row.run_link)}">folder</a>' if row.run_link else "")
        out.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    out.append("</table>")
    return out


def _job_section(i: int, row: ReportRow) -> list[str]:
    out = [
        f'<section class="job" id="job-{i}">',
        f"<h2>{_e(row.name)} {_badge(row.status)}</h2>",
        "<table>",
        f"<tr><th>Pipeline</th><td>{_e(row.pipeline)}</td></tr>",
        f"<tr><th>Input</th><td><code>{_e(row.input)}</code></td></tr>",
        f"<tr><th>Wall time</th><td>{_e(_duration(row.wall_s))}</td></tr>",
    ]
    if row.run_link:
        link = _e(row.run_link)
        out.append(f'<tr><th>Run folder</th><td><a href="{link}">{link}</a></td></tr>')
    out.append("</table>")
    if row.gates:
        out += [
            "<h3>Gates</h3>",
            "<table>",
            "<tr><th>Gate</th><th>Value</th><th>Limit</th><th>Baseline</th><th>Result</th></tr>",
        ]
        for g in row.gates:
            result = (
                '<span class="fail">✗ failed</span>' if g.failed else '<span class="pass">✓</span>'
            )
            out.append(
                f"<tr><td><code>{_e(g.gate)}</code></td>"
                f'<td class="num">{_e(format_value(g.value))}</td>'
                f'<td class="num">{_e(format_value(g.limit))}</td>'
                f'<td class="num">{_e(format_value(g.baseline))}</td>'
                f"<td>{result} {_e(g.reason)}</td></tr>"
            )
        out.append("</table>")
    names = list(row.metrics) + [k for k in row.changes if k not in row.metrics]
    if names:
        out += ["<h3>Metrics</h3>", "<table>", "<tr><th>Metric</th><th>Value</th>"]
        out[-1] += "<th>Against baseline</th></tr>" if row.changes else "</tr>"
        for k in names:
            value = row.metrics.get(k, row.changes.get(k, (None, None))[1])
            line = f'<tr><td>{_e(k)}</td><td class="num">{_e(format_value(value))}</td>'
            if row.changes:
                if k in row.changes:
                    text, css = format_change(k, *row.changes[k])
                    line += f'<td class="{css}">{_e(text)}</td>'
                else:
                    line += "<td></td>"
            out.append(line + "</tr>")
        out.append("</table>")
    if row.error:
        out += ["<h3>Error</h3>", f"<pre>{_e(row.error)}</pre>"]
    if row.report_png is not None:
        out += ["<h3>Report</h3>", _image(row.report_png, row.name)]
    out.append("</section>")
    return out


def render_html_report(
    title: str,
    rows: Sequence[ReportRow],
    *,
    baseline_label: str | None,
    generated: str,
) -> str:
    """The report as HTML text; see :func:`write_html_report`."""
    counts = {status: 0 for status in STATUS_LABELS}
    for row in rows:
        counts[row.status] = counts.get(row.status, 0) + 1
    count_items = " ".join(f"<span>{_badge(status)} {n}</span>" for status, n in counts.items())
    show_changes = baseline_label is not None or any(row.changes for row in rows)
    meta = f"Generated {_e(generated)} · {len(rows)} job{'s' if len(rows) != 1 else ''}"
    if baseline_label is not None:
        meta += f" · compared with baseline <code>{_e(baseline_label)}</code>"
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en">',
        "<head>",
        '<meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{_e(title)}</title>",
        f"<style>{_CSS}</style>",
        "</head>",
        "<body>",
        "<header>",
        f"<h1>{_e(title)}</h1>",
        f'<p class="meta">{meta}</p>',
        f'<p class="counts">{count_items}</p>',
        "</header>",
        "<main>",
        *_summary(rows, show_changes),
    ]
    for i, row in enumerate(rows, start=1):
        parts += _job_section(i, row)
    parts += ["</main>", "</body>", "</html>"]
    return "\n".join(parts) + "\n"


def write_html_report(
    path: str | Path,
    title: str,
    rows: Sequence[ReportRow],
    *,
    baseline_label: str | None,
    generated: str,
) -> Path:
    """Write the batch report for ``rows`` to ``path`` atomically; returns the path.

    The header gives the title, ``generated`` (a timestamp the caller chooses, so the output
    is reproducible) and the count of jobs per status; a summary table lists each job's gates,
    key metrics and changes against the baseline; one section per job follows with its gates,
    metrics, error text and embedded ``report.png``.
    """
    text = render_html_report(title, rows, baseline_label=baseline_label, generated=generated)
    return write_text_atomic(path, text)
