"""``slamcli batch``'s work: a manifest's jobs run on a local pool or a Dask cluster, then
``batch.json``, ``junit.xml`` and ``report.html`` beside their run folders.

:func:`plan_batch` reads and checks everything before any job runs (the manifest, each job's
settings and source options, gate metrics, baseline gates without a baseline).
:func:`run_batch` runs the jobs (each in a child process, :func:`~slamcli.batch.job.run_isolated`)
and writes the records. The CLI only parses its options, calls these and renders the result.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from slamcli.batch.gates import GateResult, metric_value
from slamcli.batch.job import JobResult, RunJob, job_config, read_run_json, result_from_run
from slamcli.batch.manifest import JobSpec, ManifestError, load_manifest
from slamcli.errors import ConfigError, InputError

BATCH_SCHEMA_VERSION = 1

KEY_METRICS = (
    "ate.rmse",
    "rpe.trans.rmse",
    "landmarks.rmse_m",
    "ms_per_frame",
    "memory.peak_rss_mb",
    "frames.lost",
)
"""Shown for every job that has them (with its gate metrics), and compared with a baseline."""

ResultFn = Callable[[JobResult, int, int], None]


@dataclass
class BatchPlan:
    """A checked manifest: its jobs as :class:`RunJob` values, in manifest order."""

    manifest: Path
    out: Path
    jobs: list[RunJob]
    specs: list[JobSpec]
    baseline: Path | None = None
    baseline_jobs: dict[str, dict[str, Any]] = field(default_factory=dict)


@dataclass
class BatchOutcome:
    """What a batch did: one result per job (manifest order) and the files it wrote."""

    plan: BatchPlan
    results: list[JobResult]
    executor: str
    files: list[Path]

    @property
    def exit_code(self) -> int:
        return batch_exit_code(self.results)

    def counts(self) -> dict[str, int]:
        out = {s: 0 for s in ("passed", "gate_failed", "data_lost", "error")}
        for r in self.results:
            out[r.status] += 1
        return out


def batch_exit_code(results: Sequence[JobResult]) -> int:
    """0 when every job passed, 1 when one could not run, else 3 (a gate failed, data lost)."""
    if any(r.status == "error" for r in results):
        return 1
    if any(r.status in ("gate_failed", "data_lost") for r in results):
        return 3
    return 0


def plan_batch(
    manifest: str | Path, out: str | Path, baseline: str | Path | None = None
) -> BatchPlan:
    """Read ``manifest`` and check every job before anything runs.

    Raises:
        ManifestError: a malformed manifest, an unknown pipeline, setting, source option or
            gate metric (naming the manifest's line and the job), or a ``k * baseline`` gate
            with no baseline given.
        InputError: ``baseline`` is not a batch folder.
    """
    from slamcli.batch.metrics import known_metric
    from slamcli.pipelines import PIPELINES

    path = Path(manifest)
    specs = load_manifest(path, pipelines=PIPELINES, check_metric=known_metric)
    out_dir = Path(out)
    base = Path(baseline) if baseline is not None else None
    baseline_jobs = _read_baseline(base) if base is not None else {}
    jobs = []
    for spec in specs:
        job = RunJob(
            pipeline=spec.pipeline,
            input=spec.input,
            out=out_dir / spec.name,
            name=spec.name,
            settings=dict(spec.settings),
            source=dict(spec.source),
            fail_if=tuple(g.text for g in spec.fail_if),
            baseline=(base / spec.name) if base is not None else None,
            max_frames=spec.max_frames,
            build_map=spec.build_map,
            mcap=spec.mcap,
            force=True,
            timeout_s=spec.timeout_s,
            command=f"batch {path.name}: {spec.name}",
        )
        for key, check in (("set", job_config), ("source", _check_source)):
            try:
                check(job)
            except ConfigError as exc:
                line = spec.key_lines.get(key, spec.line)
                raise ManifestError(path, f'job "{spec.name}": {exc.msg}', line, exc.hint) from None
        if base is None and any(g.uses_baseline for g in spec.fail_if):
            raise ManifestError(
                path,
                f'job "{spec.name}": a fail_if gate compares with a baseline, but none was given',
                spec.key_lines.get("fail_if", spec.line),
                hint="pass --baseline OLD_BATCH_DIR (the --out of an earlier batch)",
            )
        jobs.append(job)
    return BatchPlan(path, out_dir, jobs, specs, base, baseline_jobs)


def _check_source(job: RunJob) -> None:
    from slamcli.source_options import SourceOptions

    SourceOptions.from_mapping(job.source)


def _read_baseline(folder: Path) -> dict[str, dict[str, Any]]:
    record = folder / "batch.json"
    try:
        data = json.loads(record.read_text(encoding="utf-8"))
        return {str(j["name"]): j for j in data["jobs"]}
    except FileNotFoundError:
        raise InputError(
            f"{folder}: not a batch folder (no batch.json)",
            hint="--baseline takes the --out folder of an earlier 'slamcli batch'",
        ) from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"{record}: not a batch record ({exc})") from None


def is_done(job: RunJob) -> bool:
    """Whether ``job``'s run folder is a complete run of this very job: run.json present with
    every output it lists, and the same slamcli version, pipeline, settings, source options,
    run options and input hash."""
    from slamcli import __version__
    from slamcli.rundir import hash_input
    from slamcli.source_options import SourceOptions

    record = read_run_json(job.out)
    if record is None:
        return False
    if record.get("slamcli_version") != __version__ or record.get("pipeline") != job.pipeline:
        return False
    if not all((job.out / name).exists() for name in record.get("outputs", [])):
        return False
    config = record.get("config", {})
    want = _json(asdict(job_config(job)))
    source = _json(SourceOptions.from_mapping(job.source).open_kwargs())
    run = {"max_frames": job.max_frames, "mcap": job.mcap, "glb": False, "map": job.build_map}
    if (config.get(job.pipeline), config.get("source"), config.get("run")) != (want, source, run):
        return False
    inputs = record.get("inputs") or [{}]
    try:
        return bool(inputs[0].get("hash") == hash_input(job.input)["hash"])
    except InputError:
        return False


def _json(value: Any) -> Any:
    return json.loads(json.dumps(value, default=str))


def run_batch(
    plan: BatchPlan,
    *,
    jobs: int | None = None,
    scheduler: str | None = None,
    resume: bool = False,
    retries: int = 1,
    on_result: ResultFn | None = None,
) -> BatchOutcome:
    """Run ``plan``'s jobs and write ``batch.json``, ``junit.xml`` and ``report.html`` into
    its folder. A job's failure never stops the others.

    ``jobs`` processes at once on this machine (default: its cores), or every job on the Dask
    cluster at ``scheduler`` (``tcp://HOST:PORT``). With ``resume``, a job whose folder holds
    a complete run of the same job (:func:`is_done`) is not run again.
    """
    plan.out.mkdir(parents=True, exist_ok=True)
    total = len(plan.jobs)
    results: dict[int, JobResult] = {}
    todo: list[int] = []
    for i, job in enumerate(plan.jobs):
        record = read_run_json(job.out) if resume and is_done(job) else None
        if record is not None:
            result = result_from_run(
                job,
                record,
                float(sum((record.get("timings_s") or {}).values())),
                data_loss=record.get("data_loss") or [],
                skipped=int(record.get("counts", {}).get("frames_skipped", 0)),
            )
            result.resumed = True
            results[i] = result
            if on_result:
                on_result(result, len(results), total)
        else:
            todo.append(i)

    def done(i: int, result: JobResult) -> None:
        results[i] = result
        if on_result:
            on_result(result, len(results), total)

    if scheduler:
        executor = f"dask {scheduler}"
        _run_on_dask(plan, todo, scheduler, retries, done)
    else:
        workers = max(1, jobs or os.cpu_count() or 1)
        executor = f"local pool of {workers}"
        _run_locally(plan, todo, workers, retries, done)
    ordered = [results[i] for i in range(total)]
    files = write_records(plan, ordered, executor)
    return BatchOutcome(plan, ordered, executor, files)


def _run_locally(
    plan: BatchPlan,
    todo: list[int],
    workers: int,
    retries: int,
    done: Callable[[int, JobResult], None],
) -> None:
    from slamcli.batch.job import run_isolated

    # Threads only wait: each job runs in a child process of its own.
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="batch") as pool:
        futures = {pool.submit(run_isolated, plan.jobs[i], retries): i for i in todo}
        for future in as_completed(futures):
            done(futures[future], future.result())


def _run_on_dask(
    plan: BatchPlan,
    todo: list[int],
    scheduler: str,
    retries: int,
    done: Callable[[int, JobResult], None],
) -> None:
    try:
        from distributed import Client
        from distributed import as_completed as dask_completed
    except ImportError:
        raise InputError(
            "--scheduler needs Dask's distributed package, which is not installed",
            hint="pip install 'slamcli[dask]'",
        ) from None
    from slamcli.batch.job import run_isolated

    try:
        client = Client(scheduler, timeout="10s")
    except (OSError, TimeoutError) as exc:
        raise InputError(
            f"--scheduler {scheduler}: cannot reach the Dask scheduler ({exc})",
            hint="start one with 'dask scheduler' and workers with 'dask worker ADDRESS'",
        ) from None
    with client:
        futures = {
            client.submit(
                run_isolated,
                plan.jobs[i],
                retries,
                pure=False,
                key=f"slamcli-job-{i}-{plan.jobs[i].label}",
            ): i
            for i in todo
        }
        for future in dask_completed(futures):
            i = futures[future]
            try:
                result = future.result()
            except Exception as exc:  # the worker died for good: the others go on
                job = plan.jobs[i]
                result = JobResult(
                    name=job.label,
                    pipeline=job.pipeline,
                    input=str(job.input),
                    run_dir=str(job.out),
                    status="error",
                    exit_code=1,
                    wall_s=0.0,
                    error=f"{job.label}: the Dask task failed ({type(exc).__name__}: {exc})",
                )
            done(i, result)


def key_metrics(result: JobResult) -> dict[str, float]:
    """The job's key figures: :data:`KEY_METRICS` it has, and its gates' metrics."""
    names = [m for m in KEY_METRICS if m in result.metrics]
    names += [
        g.metric for g in result.gates if g.metric not in names and g.metric in result.metrics
    ]
    return {m: result.metrics[m] for m in names}


def changes(plan: BatchPlan, result: JobResult) -> dict[str, tuple[float | None, float | None]]:
    """(baseline, now) of each key metric, when a baseline was given."""
    if plan.baseline is None:
        return {}
    record = read_run_json(plan.baseline / result.name) or {}
    return {m: (metric_value(record, m), v) for m, v in key_metrics(result).items()}


def write_records(plan: BatchPlan, results: Sequence[JobResult], executor: str) -> list[Path]:
    """``batch.json``, ``junit.xml`` and ``report.html`` of a finished batch."""
    from slamcli import __version__
    from slamcli.atomic import write_json_atomic
    from slamcli.batch.html import ReportRow, write_html_report
    from slamcli.batch.junit import JunitCase, write_junit

    now = _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()
    rows = []
    for r in results:
        rows.append(
            {
                "name": r.name,
                "pipeline": r.pipeline,
                "input": r.input,
                "status": r.status,
                "exit_code": r.exit_code,
                "run_dir": os.path.relpath(r.run_dir, plan.out),
                "gates": [asdict(g) for g in r.gates],
                "metrics": key_metrics(r),
                "changes": {m: list(v) for m, v in changes(plan, r).items()},
                "counts": r.counts,
                "wall_s": round(r.wall_s, 3),
                "error": r.error,
                "hint": r.hint,
                "attempts": r.attempts,
                "resumed": r.resumed,
            }
        )
    counts = {
        s: sum(1 for r in results if r.status == s)
        for s in ("passed", "gate_failed", "data_lost", "error")
    }
    record = {
        "schema_version": BATCH_SCHEMA_VERSION,
        "slamcli_version": __version__,
        "manifest": str(plan.manifest.resolve()),
        "created": now,
        "executor": executor,
        "baseline": str(plan.baseline.resolve()) if plan.baseline is not None else None,
        "counts": counts,
        "exit_code": batch_exit_code(results),
        "jobs": rows,
    }
    files = [write_json_atomic(plan.out / "batch.json", record)]
    cases = [
        JunitCase(
            name=r.name,
            classname=r.pipeline,
            time_s=r.wall_s,
            status=r.status,
            message=r.error,
            details="\n".join(
                [g.reason for g in r.gates]
                + ([r.hint] if r.hint else [])
                + ([r.details] if r.details else [])
            ),
            properties={k: f"{v:g}" for k, v in key_metrics(r).items()},
        )
        for r in results
    ]
    files.append(write_junit(plan.out / "junit.xml", f"slamcli batch {plan.manifest.name}", cases))
    report_rows = [
        ReportRow(
            name=r.name,
            pipeline=r.pipeline,
            input=r.input,
            status=r.status,
            wall_s=r.wall_s,
            gates=list(r.gates),
            metrics=key_metrics(r),
            changes=changes(plan, r),
            run_link=f"{os.path.relpath(r.run_dir, plan.out)}/" if Path(r.run_dir).is_dir() else "",
            report_png=(Path(r.run_dir) / "report.png")
            if (Path(r.run_dir) / "report.png").exists()
            else None,
            error="\n".join(x for x in (r.error, r.hint) if x),
        )
        for r in results
    ]
    files.append(
        write_html_report(
            plan.out / "report.html",
            f"slamcli batch {plan.manifest.name}",
            report_rows,
            baseline_label=str(plan.baseline) if plan.baseline is not None else None,
            generated=now,
        )
    )
    return files


def gate_lines(gates: Sequence[GateResult]) -> list[str]:
    """One line per gate, as the console and JUnit show them."""
    return [("FAIL " if g.failed else "ok   ") + g.reason for g in gates]
