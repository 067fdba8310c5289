"""One run as a value: :class:`RunJob` in, :func:`run_job` does it, :class:`JobResult` out.

``slamcli run``, ``slamcli batch`` and a Dask worker all end here. A :class:`RunJob` is
picklable (paths, numbers, strings, small tables); a :class:`JobResult` carries what the run
measured (status, metrics, counts, timings, the files written, gate results, the error and the
exit code), never meshes or images: those stay in the run folder.

:func:`run_job` runs in the calling process. :func:`run_isolated` runs the same call in a child
process (``python -m slamcli.batch.job``): a job that exceeds its ``timeout_s`` is killed with
its own children, and a child that dies (a segfault in a native library, the OOM killer) is
tried again up to ``retries`` times. Either way the run folder is all or nothing, and the
trajectory is the same bytes whichever process ran it.

Statuses and exit codes: ``passed`` (0), ``gate_failed`` (3: a ``fail_if`` gate held),
``data_lost`` (3: frames skipped or a damaged log salvaged), ``error`` (the error's own code: 1
for bad input, a timeout or a crash).
"""

from __future__ import annotations

import json
import logging
import os
import pickle
import signal
import subprocess
import sys
import time
import traceback
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from slamcli.batch.gates import GateResult, evaluate_gates, flatten_metrics, parse_gate
from slamcli.errors import SlamcliError

log = logging.getLogger(__name__)

STATUSES = ("passed", "gate_failed", "data_lost", "error")
EXIT_CODES = {"passed": 0, "gate_failed": 3, "data_lost": 3}


@dataclass(frozen=True)
class RunJob:
    """What ``slamcli run PIPELINE INPUT --out OUT`` with its options does, as a value.

    ``settings`` are config overrides (``--set NAME=VALUE``; values as TOML gives them),
    ``source`` the source options by name (``--max-dt``, ``--robot``, ...), ``fail_if`` gate
    texts, ``baseline`` a baseline run folder whose run.json gates of the form ``k * baseline``
    compare with.
    """

    pipeline: str
    input: Path
    out: Path
    name: str = ""
    settings: Mapping[str, Any] = field(default_factory=dict)
    config_file: Path | None = None
    source: Mapping[str, Any] = field(default_factory=dict)
    fail_if: tuple[str, ...] = ()
    baseline: Path | None = None
    max_frames: int | None = None
    build_map: bool = False
    mcap: bool = False
    force: bool = False
    timeout_s: float | None = None
    command: str = ""

    @property
    def label(self) -> str:
        return self.name or self.out.name


@dataclass
class JobResult:
    """What a job did. ``metrics`` holds every numeric figure of run.json under the names
    gates use (``ate.rmse``, ``frames.lost``, ``ms_per_frame``); ``gates`` one record per
    gate; ``error`` and ``hint`` the failure's one-line message, ``details`` its longer form
    (a traceback for an internal error)."""

    name: str
    pipeline: str
    input: str
    run_dir: str
    status: str
    exit_code: int
    wall_s: float
    metrics: dict[str, float] = field(default_factory=dict)
    counts: dict[str, Any] = field(default_factory=dict)
    timings: dict[str, float] = field(default_factory=dict)
    outputs: list[str] = field(default_factory=list)
    gates: list[GateResult] = field(default_factory=list)
    data_loss: list[str] = field(default_factory=list)
    error: str = ""
    hint: str = ""
    details: str = ""
    attempts: int = 1
    resumed: bool = False

    @property
    def failed_gates(self) -> list[GateResult]:
        return [g for g in self.gates if g.failed]

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> JobResult:
        values = dict(data)
        values["gates"] = [GateResult(**g) for g in values.get("gates", [])]
        known = cls.__dataclass_fields__
        return cls(**{k: v for k, v in values.items() if k in known})


def settings_as_sets(settings: Mapping[str, Any]) -> list[str]:
    """``--set`` texts (``NAME=VALUE``, the value as TOML) for a table of overrides."""
    from slamcli.config import _toml_value

    return [f"{key}={_toml_value(value)}" for key, value in settings.items()]


def job_config(job: RunJob) -> Any:
    """The pipeline's config the job runs with (defaults, then its file, then its settings)."""
    from slamcli.config import load_config
    from slamcli.pipelines import get_pipeline

    cls = get_pipeline(job.pipeline).config_class
    return load_config(cls, job.pipeline, job.config_file, settings_as_sets(job.settings))


def read_run_json(run_dir: Path) -> dict[str, Any] | None:
    """A run folder's run.json, or None when there is none or it cannot be read."""
    try:
        data = json.loads((Path(run_dir) / "run.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def result_from_run(
    job: RunJob,
    record: Mapping[str, Any],
    wall_s: float,
    data_loss: Sequence[str] = (),
    skipped: int = 0,
) -> JobResult:
    """A finished run's result: its figures, its gates (against the job's baseline), and the
    status they give."""
    baseline = read_run_json(job.baseline) if job.baseline is not None else None
    gates = evaluate_gates([parse_gate(g) for g in job.fail_if], record, baseline)
    status = "passed"
    if any(g.failed for g in gates):
        status = "gate_failed"
    elif skipped or data_loss:
        status = "data_lost"
    error = ""
    if skipped:
        error = f"{skipped} frame(s) skipped because they were missing or unreadable"
    elif data_loss:
        error = "the log is damaged; the run used what could be read"
    if status == "gate_failed":
        error = "; ".join(g.reason for g in gates if g.failed)
    counts = dict(record.get("counts") or {})
    return JobResult(
        name=job.label,
        pipeline=job.pipeline,
        input=str(job.input),
        run_dir=str(job.out),
        status=status,
        exit_code=EXIT_CODES[status],
        wall_s=wall_s,
        metrics=flatten_metrics(record),
        counts=counts,
        timings=dict(record.get("timings_s") or {}),
        outputs=[str(job.out / name) for name in record.get("outputs", [])],
        gates=gates,
        data_loss=list(data_loss),
        error=error,
    )


def run_job(job: RunJob) -> JobResult:
    """Run ``job`` in this process; every failure becomes a result with status ``error``
    (Ctrl-C still interrupts)."""
    from slamcli.run import run_pipeline
    from slamcli.source_options import SourceOptions

    start = time.perf_counter()
    try:
        for gate in job.fail_if:
            parse_gate(gate)
        config = job_config(job)
        source = SourceOptions.from_mapping(job.source).open_kwargs()
        outcome = run_pipeline(
            job.input,
            job.pipeline,
            job.out,
            force=job.force,
            config=config,
            source_options=source,
            max_frames=job.max_frames,
            command=job.command or f"run {job.pipeline}",
            mcap=job.mcap,
            build_map=job.build_map,
        )
    except SlamcliError as exc:
        return _error(job, start, exc.msg, exc.hint or "", exc.exit_code)
    except OSError as exc:
        from slamcli.atomic import os_error

        err = os_error(exc)
        return _error(job, start, err.msg, err.hint or "", err.exit_code)
    except Exception as exc:  # a bug: reported with its traceback, the other jobs go on
        return _error(
            job,
            start,
            f"internal error: {type(exc).__name__}: {exc}",
            "",
            1,
            details=traceback.format_exc(),
        )
    return result_from_run(
        job,
        outcome.record,
        time.perf_counter() - start,
        data_loss=outcome.data_loss,
        skipped=int(outcome.counts.get("frames_skipped", 0)),
    )


def _error(
    job: RunJob,
    start: float,
    message: str,
    hint: str,
    code: int,
    details: str = "",
) -> JobResult:
    return JobResult(
        name=job.label,
        pipeline=job.pipeline,
        input=str(job.input),
        run_dir=str(job.out),
        status="error",
        exit_code=code or 1,
        wall_s=time.perf_counter() - start,
        error=message,
        hint=hint,
        details=details,
    )


def run_isolated(job: RunJob, retries: int = 1) -> JobResult:
    """:func:`run_job` in a child process, with the job's timeout and up to ``retries`` more
    tries when the child dies instead of answering."""
    from slamcli.rundir import clean_stale_staging

    start = time.perf_counter()
    attempts = 0
    reason = ""
    while attempts <= retries:
        attempts += 1
        answer, reason = _child(job)
        if answer is not None:
            answer.attempts = attempts
            return answer
        clean_stale_staging(job.out)
        if reason.startswith("timed out"):
            break
        log.warning("%s: %s; trying again", job.label, reason)
    result = _error(job, start, f"{job.label}: {reason}", _crash_hint(reason), 1)
    result.attempts = attempts
    return result


def _crash_hint(reason: str) -> str:
    if reason.startswith("timed out"):
        return "raise the job's timeout_s, or run fewer frames (max_frames)"
    return "run the job alone with 'slamcli run' to see what stops it"


def _child(job: RunJob) -> tuple[JobResult | None, str]:
    """One try in a child process: its answer, or None and why there is none."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "slamcli.batch.job"],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,  # its own process group: a timeout stops its helpers too
    )
    try:
        out, err = proc.communicate(pickle.dumps(job), timeout=job.timeout_s)
    except subprocess.TimeoutExpired:
        _kill_group(proc)
        return None, f"timed out after {job.timeout_s:g} s"
    except BaseException:
        _kill_group(proc)
        raise
    if proc.returncode == 0 and out:
        try:
            answer = pickle.loads(out)
        except (pickle.UnpicklingError, EOFError, AttributeError, ValueError):
            answer = None
        if isinstance(answer, JobResult):
            return answer, ""
    tail = err.decode("utf-8", "replace").strip().splitlines()[-3:]
    code = proc.returncode
    how = f"killed by signal {-code}" if code < 0 else f"exit code {code}"
    return None, f"the job's process stopped ({how})" + (f": {' / '.join(tail)}" if tail else "")


def _kill_group(proc: subprocess.Popen[bytes]) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        proc.kill()
    proc.communicate()


def _serve() -> None:
    """The child: a pickled job on stdin, its pickled result on stdout."""
    # Run as ``python -m``, this module is __main__: the result must be the importable
    # module's class for the parent to unpickle it.
    from slamcli.batch import job as module

    job = pickle.loads(sys.stdin.buffer.read())
    answer = sys.stdout.buffer
    sys.stdout = sys.stderr  # nothing else may write to the answer
    result = module.run_job(job)
    answer.write(pickle.dumps(result))
    answer.flush()


if __name__ == "__main__":
    _serve()
