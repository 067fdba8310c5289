"""All terminal output: messages, tables, progress bars and JSON.

Results go to stdout; messages, warnings and progress go to stderr, so ``--json`` output
stays a single clean JSON document.
"""

from __future__ import annotations

import contextlib
import json
import logging
import sys
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from slamcli.errors import SlamcliError

if TYPE_CHECKING:
    from slamcli.kernels import KernelGroup
    from slamcli.run import RunOutcome
    from slamcli.types import ProgressFn

out = Console(highlight=False, soft_wrap=True, emoji=False)
err = Console(stderr=True, highlight=False, soft_wrap=True, emoji=False)


class _StderrHandler(logging.Handler):
    _STYLE: ClassVar[dict[str, str]] = {"WARNING": "yellow", "ERROR": "red", "CRITICAL": "red"}

    def emit(self, record: logging.LogRecord) -> None:
        level = record.levelname
        style = self._STYLE.get(level, "dim")
        err.print(f"[{style}]{level.lower()}:[/] {escape(record.getMessage())}")


def setup_logging(verbose: int) -> None:
    """Route the library's log records to stderr: warnings by default, -v info, -vv debug."""
    level = logging.WARNING if verbose <= 0 else logging.INFO if verbose == 1 else logging.DEBUG
    root = logging.getLogger("slamcli")
    for h in list(root.handlers):
        if isinstance(h, _StderrHandler):
            root.removeHandler(h)
    root.addHandler(_StderrHandler())
    root.setLevel(level)


def error(exc: SlamcliError) -> None:
    """The one-line red error, plus its hint on a second line."""
    err.print(f"[bold red]error:[/] {escape(exc.msg)}")
    if exc.hint:
        err.print(f"[dim]hint:[/] {escape(exc.hint)}")


def warn(msg: str) -> None:
    err.print(f"[yellow]warning:[/] {escape(msg)}")


def note(msg: str) -> None:
    err.print(escape(msg))


def compiling(group: KernelGroup) -> None:
    """The one line, before the wait, that says a group of kernels is being compiled."""
    err.print(
        f"slamcli: compiling the {group.title} kernels for this machine, once "
        f"(about {group.seconds:.0f} s)"
    )


def print_json(data: Any) -> None:
    """Exactly one JSON document on stdout."""
    sys.stdout.write(json.dumps(data, indent=2) + "\n")
    sys.stdout.flush()


def heading(text: str) -> None:
    """A section heading between the blocks of a command that does several things."""
    out.print(f"\n[bold]{text}[/]", markup=True)


def plain(text: str) -> None:
    """Text exactly as given on stdout, without markup (file contents such as TOML)."""
    sys.stdout.write(text)
    sys.stdout.flush()


def table(
    title: str | None,
    columns: Sequence[str],
    rows: Sequence[Sequence[Any]],
    right_align: Sequence[str] = (),
    stderr: bool = False,
) -> None:
    t = Table(title=title, title_justify="left", show_edge=False, header_style="bold")
    for c in columns:
        t.add_column(c, justify="right" if c in right_align else "left")
    for r in rows:
        t.add_row(*(escape(str(v)) for v in r))
    (err if stderr else out).print(t)


def key_values(title: str | None, items: Mapping[str, Any]) -> None:
    t = Table(title=title, title_justify="left", show_header=False, show_edge=False, box=None)
    t.add_column(style="bold")
    t.add_column()
    for k, v in items.items():
        t.add_row(escape(str(k)), escape(str(v)))
    out.print(t)


def written(paths: Sequence[str | Path], title: str = "Written") -> None:
    """One line per file with its size; paths are never shortened, so they can be copied."""
    out.print(title)
    sizes = [str(Path(p).stat().st_size) for p in paths]
    width = max((len(s) for s in sizes), default=0)
    for path, size in zip(paths, sizes, strict=True):
        out.print(f" {size:>{width}} bytes  {escape(str(path))}", soft_wrap=True)


@contextlib.contextmanager
def progress(description: str, total: int | None = None) -> Iterator[ProgressFn]:
    """A progress bar on stderr (terminal only); yields a ``progress(done, total)`` callback."""
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    bar = Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=err,
        transient=True,
        disable=not err.is_terminal,
    )
    with bar:
        task = bar.add_task(description, total=total)

        def update(done: int, total_now: int | None = None) -> None:
            bar.update(task, completed=done, total=total_now if total_now is not None else total)

        def nothing(done: int, total_now: int | None = None) -> None:
            pass

        # Without a terminal nothing is drawn: a log of 300,000 rows need not pay for updates.
        yield nothing if bar.disable else update


def _planar_summary(metrics: dict[str, Any], counts: dict[str, Any]) -> None:
    """The accuracy table of a planar landmark run: ATE beside dead reckoning, landmarks, NEES."""
    ev = metrics.get("evaluation")
    if ev:
        _planar_accuracy(metrics, ev)
    nees = (ev or {}).get("nees")
    summary = {
        "landmarks": counts.get("landmarks", 0),
        "updates": counts.get("updates", 0),
        "rejected by gate": counts.get("rejected_by_gate", 0),
        "new / merged / pruned": f"{counts.get('landmarks_new', 0)} / "
        f"{counts.get('landmarks_merged', 0)} / {counts.get('landmarks_pruned', 0)}",
    }
    nis = metrics.get("nis")
    if nis:
        summary["NIS (2 dof)"] = (
            f"mean {nis['mean']:.2f}, {100 * nis['fraction_in_band']:.0f}% inside the 95% band"
        )
    if nees:
        summary["NEES (3 dof), filter"] = (
            f"mean {nees['mean']:.2f}, {100 * nees['fraction_in_band']:.0f}% inside the 95% band"
        )
    key_values("Filter", summary)


def _scan_summary(metrics: dict[str, Any], counts: dict[str, Any]) -> None:
    """The accuracy table of a lidar run (ATE, RPE over 1 s and 10 s) and its scan matching."""
    ev = metrics.get("evaluation")
    if ev:
        rows = [
            ["ATE (m), SE(2) aligned", *(f"{ev['ate'][k]:.4f}" for k in ("rmse", "mean", "max"))]
        ]
        for span, rpe in (ev.get("rpe") or {}).items():
            rows.append(
                [
                    f"RPE over {span} ({rpe['pairs']} pairs), m",
                    *(f"{rpe['trans'][k]:.4f}" for k in ("rmse", "mean", "max")),
                ]
            )
            rows.append(
                [
                    f"RPE over {span}, deg",
                    *(f"{rpe['rot_deg'][k]:.3f}" for k in ("rmse", "mean", "max")),
                ]
            )
        table(
            f"Accuracy against ground truth ({ev['matched']} poses, SE(2) alignment)",
            ["metric", "rmse", "mean", "max"],
            rows,
            right_align=["rmse", "mean", "max"],
        )
    per_scan = metrics.get("ms_per_frame") or {}
    key_values(
        "Scan matching",
        {
            "scans / nodes / submaps": f"{counts.get('scans', 0)} / {counts.get('nodes', 0)} / "
            f"{counts.get('submaps', 0)}",
            "scans not matched": counts.get("scans_not_matched", 0),
            "loops closed": counts.get("loops_closed", 0),
            "loops rejected (fit / graph)": f"{counts.get('loops_rejected_by_fit', 0)} / "
            f"{counts.get('loops_rejected_by_graph', 0)}",
            "ms per scan": f"{per_scan.get('total', 0.0):.1f}",
        },
    )


def _planar_accuracy(metrics: dict[str, Any], ev: dict[str, Any]) -> None:
    rows = [["ATE (m), SE(2) aligned", *(f"{ev['ate'][k]:.4f}" for k in ("rmse", "mean", "max"))]]
    filt = metrics.get("filtered")
    if filt:
        rows[0][0] = "ATE (m), smoothed, SE(2) aligned"
        rows.append(
            ["ATE (m), filter alone", *(f"{filt['ate'][k]:.4f}" for k in ("rmse", "mean", "max"))]
        )
    dr = metrics.get("dead_reckoning")
    if dr:
        rows.append(
            ["dead reckoning ATE (m)", *(f"{dr['ate'][k]:.4f}" for k in ("rmse", "mean", "max"))]
        )
    lm = ev.get("landmarks") or {}
    if lm.get("rmse_m") is not None:
        rows.append(
            [f"landmark error (m), {lm.get('matched', 0)} matched", f"{lm['rmse_m']:.4f}", "", ""]
        )
    table(
        f"Accuracy against ground truth ({ev['matched']} poses, SE(2) alignment)",
        ["metric", "rmse", "mean", "max"],
        rows,
        right_align=["rmse", "mean", "max"],
    )


def run_summary(outcome: RunOutcome) -> None:
    """The input, the accuracy table (when the run was scored) and the files a run wrote."""
    info = outcome.info
    processed = outcome.counts.get("frames_processed", 0)
    facts: dict[str, Any] = {
        "data": outcome.input_path,
        "format": info.format,
        # info's count is an estimate for some logs (MCAP counts RGB-D pairs by log time).
        "frames": f"{processed} processed of {info.frames}"
        if info.frames >= processed
        else f"{processed} processed",
        "ground-truth poses": info.groundtruth,
    }
    if info.camera_source:
        facts["camera"] = info.camera_source
    key_values("Input", facts)
    ev = outcome.metrics.get("evaluation")
    if outcome.result.grid is not None:
        _scan_summary(outcome.metrics, outcome.counts)
    elif outcome.evaluation == "se2":
        _planar_summary(outcome.metrics, outcome.counts)
    elif ev:
        stats = [("ATE (m)", ev["ate"])]
        if "rpe" in ev:
            stats.append(("RPE translation (m/frame)", ev["rpe"]["trans"]))
            stats.append(("RPE rotation (deg/frame)", ev["rpe"]["rot_deg"]))
        table(
            f"Accuracy against ground truth ({ev['pairs']} poses, {ev['alignment']} alignment)",
            ["metric", "rmse", "mean", "max"],
            [[name, *(f"{s[k]:.4f}" for k in ("rmse", "mean", "max"))] for name, s in stats],
            right_align=["rmse", "mean", "max"],
        )
    written(outcome.outputs)
    for problem in outcome.data_loss:
        warn(problem)
    for doubt in outcome.metrics.get("doubts", ()):
        warn(f"the result may be wrong: {doubt} (gate on it with --fail-if 'doubts > 0')")
