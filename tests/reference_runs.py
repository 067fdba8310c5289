"""Reference runs: commands whose outputs are recorded in ``tests/reference/`` and must come out
the same after any change that is meant to move code, not change results.

``python tests/reference_runs.py`` runs every command on this machine and records, for each,
the output files named in :data:`RUNS` (and for ``plan`` the search's cost from ``plan.json``),
with ``recorded.json`` naming the commit, the machine and the library versions.
``tests/test_reference_runs.py`` runs the same commands and compares: byte for byte on a
machine of the recorded kind (same CPU model and flags, same library versions), within the
tolerances of :data:`RUNS` elsewhere (floating-point rounding differs across CPUs and library
builds, and a visual tracker's choices follow it).

Every command runs in-process through the CLI's own entry point, once per test session
(:func:`run_once`), so the tests that read these runs share them.

The same machinery shares any command or artefact that several tests need: :func:`run_shared`
runs a ``slamcli`` command once per session, keyed by its arguments (a reference run is one of
them), and :func:`make_once` makes any other expensive input once.
"""

from __future__ import annotations

import argparse
import contextlib
import fcntl
import hashlib
import json
import os
import platform
import re
import shutil
import subprocess
import traceback
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
RECORDED = HERE / "reference"
SHARED_DATA = Path(
    os.environ.get("SLAMCLI_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data")
)
TUM = "{shared}/tum/rgbd_dataset_freiburg1_rpy_excerpt"
ROOM = "{repo}/sample_data/rgbd_room"
MRCLAM = "{shared}/landmarks/MRCLAM_Dataset6"
NAV2_MAP = "{shared}/maps/turtlebot3_world.yaml"
INTEL = "{shared}/pose_graphs/intel.g2o"

LIBRARIES = ("numpy", "scipy", "opencv-python-headless", "open3d-cpu", "pycolmap", "gtsam")


@dataclass(frozen=True)
class Run:
    """One reference command (``argv`` after ``slamcli``, without ``--out``), the files it
    writes that are compared, and the largest position difference (m) accepted on a machine
    of another kind."""

    argv: tuple[str, ...]
    files: tuple[str, ...]
    tolerance_m: float

    def arguments(self) -> list[str]:
        """``argv`` with this machine's data and repository folders filled in."""
        subs = {"shared": str(SHARED_DATA), "repo": str(REPO)}
        return [a.format(**subs) for a in self.argv]

    def command(self, out: Path) -> list[str]:
        return [*self.arguments(), "--out", str(out)]


RUNS: dict[str, Run] = {
    "visual_tum": Run(("run", "visual", TUM), ("trajectory.tum", "keyframes.tum"), 0.02),
    "visual_room": Run(("run", "visual", ROOM), ("trajectory.tum", "keyframes.tum"), 0.02),
    "mono_tum": Run(
        ("run", "visual", TUM, "--set", "mode=mono"), ("trajectory.tum", "keyframes.tum"), 0.05
    ),
    "dense_tum": Run(("run", "dense", TUM), ("trajectory.tum", "keyframes.tum"), 0.02),
    "dense_room": Run(("run", "dense", ROOM), ("trajectory.tum", "keyframes.tum"), 0.02),
    "ekf_mrclam1": Run(
        ("run", "ekf", MRCLAM, "--robot", "1"),
        ("trajectory.tum", "trajectory_filtered.tum", "landmarks.csv"),
        1e-4,
    ),
    "graph_mrclam1": Run(
        ("run", "graph", MRCLAM, "--robot", "1"), ("trajectory.tum", "landmarks.csv"), 1e-4
    ),
    "plan_nav2": Run(
        ("plan", NAV2_MAP, "--start", "-2,-0.5", "--goal", "2,0.5"),
        ("path.csv", "path_smooth.csv", "trajectory.csv"),
        1e-6,
    ),
    "optimize_intel": Run(("graph", "optimize", INTEL), ("optimized.g2o", "trajectory.tum"), 1e-6),
}
"""The reference runs by name."""

PLAN_COST = "plan_cost.json"
"""What is kept of plan.json: the search's exact costs."""

DIGESTS = "digests.json"
"""Each compared file's SHA-256, size and number of lines."""

KEEP_WHOLE_BYTES = 100_000
"""Files up to this size are kept whole; of a larger one, every :data:`SAMPLE_EVERY`-th line
(and the last), in ``NAME.sample`` as ``line-number<TAB>line``."""
SAMPLE_EVERY = 50


def digest(path: Path) -> dict[str, object]:
    """SHA-256, size and line count of a file."""
    data = path.read_bytes()
    return {
        "sha256": hashlib.sha256(data).hexdigest(),
        "bytes": len(data),
        "lines": data.count(b"\n"),
    }


def sample_lines(lines: list[str]) -> dict[int, str]:
    """The lines kept of a large file, by their 0-based line number."""
    keep = set(range(0, len(lines), SAMPLE_EVERY)) | ({len(lines) - 1} if lines else set())
    return {i: lines[i] for i in sorted(keep)}


def kept_lines(name: str, file: str) -> dict[int, str]:
    """The recorded lines of ``file`` of run ``name``: all of them, or its sample."""
    whole = RECORDED / name / file
    if whole.exists():
        return dict(enumerate(whole.read_text().splitlines()))
    out = {}
    for row in (RECORDED / name / f"{file}.sample").read_text().splitlines():
        number, _, line = row.partition("\t")
        out[int(number)] = line
    return out


def machine() -> dict[str, object]:
    """What decides whether outputs can be compared byte for byte: the CPU (model and
    instruction-set flags), the Python and the numerical libraries' versions."""
    model, flags = "", ""
    with contextlib.suppress(OSError):
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name" and not model:
                model = value.strip()
            if key.strip() == "flags" and not flags:
                flags = " ".join(sorted(value.split()))
    versions = {}
    for name in LIBRARIES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return {
        "arch": platform.machine(),
        "cpu": model,
        "cpu_flags_sha256": hashlib.sha256(flags.encode()).hexdigest()[:16],
        "python": platform.python_version(),
        "libraries": versions,
    }


def plan_costs(plan_json: Path) -> dict[str, object]:
    """The figures of plan.json that the search defines exactly."""
    record = json.loads(plan_json.read_text())
    return {k: record[k] for k in ("grid_cost_m", "start_cell", "goal_cell") if k in record}


@contextlib.contextmanager
def _locked(path: Path) -> Iterator[None]:
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def run_in_process(argv: list[str]) -> tuple[int, str]:
    """``slamcli ARGV`` through the CLI's entry point, in this process: exit code and output."""
    from typer.testing import CliRunner

    from slamcli.cli.app import app

    result = CliRunner().invoke(app, argv)
    return result.exit_code, result.output


def run_once(name: str, root: Path) -> Path:
    """The run folder of reference run ``name`` under ``root``, made the first time any test
    process of the session asks for it (the others wait for it, then read it)."""
    run = run_shared(RUNS[name].arguments(), root)
    if run.exit_code != 0:
        raised = f" raising {run.exception}\n{run.traceback}" if run.exception else ""
        raise RuntimeError(f"reference run {name} exited {run.exit_code}{raised}:\n{run.output}")
    return run.out


# --- commands and artefacts shared by the tests of one session ------------------------------------


@dataclass(frozen=True)
class SharedRun:
    """A command run once for the whole test session, and what it printed.

    ``out`` is its ``--out``; it is shared, so a test reads it and never changes it (copy it
    first, :func:`copy_out`). ``exception`` is the repr of an exception other than
    ``SystemExit`` that the command raised, else None, and ``traceback`` its traceback.
    """

    argv: tuple[str, ...]
    out: Path
    exit_code: int
    output: str
    stdout: str
    stderr: str
    exception: str | None
    traceback: str = ""


def _exists(path: Path) -> bool:
    try:
        return path.exists()
    except (OSError, ValueError):  # not a path: too long, or with a NUL
        return False


def _is_option(token: str, name: str) -> bool:
    return token == name or token.startswith(f"{name}=")


def shared_arguments(argv: Sequence[str | Path], cwd: Path | None = None) -> tuple[str, ...]:
    """What decides a command's result: ``argv`` without ``--out`` (a shared run writes its own
    folder) and ``--force`` (which only matters for a folder that exists, and a shared run's
    never does), with every argument that names an existing path made absolute and resolved,
    so that the same command given from another folder, or through a symlink, is the same."""
    base = Path.cwd() if cwd is None else cwd
    out: list[str] = []
    tokens = [str(t) for t in argv]
    i = 0
    while i < len(tokens):
        token = tokens[i]
        if token == "--out":
            i += 2
            continue
        if _is_option(token, "--out") or token == "--force":
            i += 1
            continue
        if not token.startswith("-") and _exists(base / token):
            token = str((base / token).resolve())
        out.append(token)
        i += 1
    return tuple(out)


def out_argument(argv: Sequence[str | Path]) -> str | None:
    """The value of ``--out`` in ``argv``, if any."""
    tokens = [str(t) for t in argv]
    for i, token in enumerate(tokens):
        if token == "--out" and i + 1 < len(tokens):
            return tokens[i + 1]
        if token.startswith("--out="):
            return token.split("=", 1)[1]
    return None


def shareable_example(args: Sequence[str], work: Path) -> bool:
    """Whether a documented example (``args`` after ``slamcli``, run in the folder ``work``) can
    be a shared run whose ``--out`` is copied into ``work``: it writes a new ``--out`` and reads
    nothing of ``work`` (only the repository's and the shared data, through links or not)."""
    out = out_argument(args)
    if out is None or _exists(work / out):
        return False
    root = work.resolve()
    for token in args:
        if token == out:
            continue
        for part in {token, token.split("=", 1)[-1]}:
            path = work / part
            if _exists(path):
                if root in path.resolve().parents:
                    return False
            elif "/" in part:
                return False  # a path to be written, or one that is not there
    return True


def _key(arguments: tuple[str, ...], suffix: str) -> str:
    words = [t for t in arguments if not t.startswith("-") and "/" not in t][:3]
    slug = re.sub(r"[^A-Za-z0-9]+", "-", "-".join(words)).strip("-")[:40] or "run"
    digest = hashlib.sha256(json.dumps([arguments, suffix]).encode()).hexdigest()[:12]
    return f"{slug}-{digest}"


def run_shared(
    argv: Sequence[str | Path], root: Path, *, cwd: Path | None = None, suffix: str = ""
) -> SharedRun:
    """``slamcli ARGV`` run once per test session under ``root``, whichever test process asks
    first (the others wait for it, then read what it wrote and printed).

    Commands that differ only in ``--out`` and ``--force``, or in how they name the same
    input (see :func:`shared_arguments`), are one run. ``suffix`` is the ``--out`` name's
    suffix for commands whose ``--out`` is a file (``.npz``, ``.ply``), part of the key.
    The command runs in-process through the CLI's entry point, in a folder of its own.
    """
    arguments = shared_arguments(argv, cwd)
    key = _key(arguments, suffix)
    folder = root / key
    out = folder / f"out{suffix}"
    record = root / f"{key}.json"
    with _locked(root / f"{key}.lock"):
        if not record.exists():
            from typer.testing import CliRunner

            from slamcli.cli.app import app

            if folder.exists():
                shutil.rmtree(folder)
            folder.mkdir(parents=True)
            with contextlib.chdir(folder):
                result = CliRunner().invoke(app, [*arguments, "--out", str(out)])
            exception = result.exception
            raised = exception is not None and not isinstance(exception, SystemExit)
            trace = ""
            if raised and result.exc_info is not None:
                trace = "".join(traceback.format_exception(*result.exc_info))
            record.write_text(
                json.dumps(
                    {
                        "argv": arguments,
                        "exit_code": result.exit_code,
                        "output": result.output,
                        "stdout": result.stdout,
                        "stderr": result.stderr,
                        "exception": repr(exception) if raised else None,
                        "traceback": trace,
                    }
                )
            )
    done = json.loads(record.read_text())
    return SharedRun(
        argv=tuple(done["argv"]),
        out=out,
        exit_code=done["exit_code"],
        output=done["output"],
        stdout=done["stdout"],
        stderr=done["stderr"],
        exception=done["exception"],
        traceback=done["traceback"],
    )


def copy_out(run: SharedRun, dest: Path) -> Path:
    """A private copy of a shared run's output (a folder or a file) at ``dest``, to change."""
    dest.parent.mkdir(parents=True, exist_ok=True)
    if run.out.is_dir():
        shutil.copytree(run.out, dest, symlinks=True)
    elif run.out.exists():
        shutil.copy2(run.out, dest)
    return dest


def make_once(key: str, root: Path, make: Callable[[Path], object]) -> Path:
    """The folder ``root/key``, filled by ``make(folder)`` once per test session, whichever test
    process asks first (the others wait for it). A ``make`` that fails leaves nothing, and
    the next test to ask tries again (and fails with its own traceback)."""
    folder = root / key
    done = root / f"{key}.done"
    with _locked(root / f"{key}.lock"):
        if not done.exists():
            if folder.exists():
                shutil.rmtree(folder)
            folder.mkdir(parents=True)
            try:
                make(folder)
            except BaseException:
                shutil.rmtree(folder, ignore_errors=True)
                raise
            done.touch()
    return folder


def record(names: list[str]) -> None:
    """Run ``names`` into a scratch folder and keep their compared files in tests/reference/."""
    import tempfile

    commit = subprocess.run(
        ["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True, check=True
    ).stdout.strip()
    index_path = RECORDED / "recorded.json"
    index = json.loads(index_path.read_text()) if index_path.exists() else {"runs": {}}
    with tempfile.TemporaryDirectory() as scratch:
        for name in names:
            spec = RUNS[name]
            out = Path(scratch) / name
            code, output = run_in_process(spec.command(out))
            if code != 0:
                raise SystemExit(f"{name}: exit code {code}\n{output}")
            keep = RECORDED / name
            if keep.exists():
                shutil.rmtree(keep)
            keep.mkdir(parents=True)
            digests = {}
            for file in spec.files:
                digests[file] = digest(out / file)
                if (out / file).stat().st_size <= KEEP_WHOLE_BYTES:
                    shutil.copyfile(out / file, keep / file)
                else:
                    lines = (out / file).read_text().splitlines()
                    sample = sample_lines(lines)
                    (keep / f"{file}.sample").write_text(
                        "".join(f"{i}\t{line}\n" for i, line in sample.items())
                    )
            (keep / DIGESTS).write_text(json.dumps(digests, indent=1, sort_keys=True) + "\n")
            if (out / "plan.json").exists():
                (keep / PLAN_COST).write_text(
                    json.dumps(plan_costs(out / "plan.json"), indent=1) + "\n"
                )
            index["runs"][name] = {
                "command": ["slamcli", *spec.argv, "--out", "OUT"],
                "commit": commit,
            }
            print(f"recorded {name}")
    index["machine"] = machine()
    index_path.write_text(json.dumps(index, indent=1, sort_keys=True) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description="Record the reference runs' outputs.")
    parser.add_argument("names", nargs="*", help="runs to record (default: all)")
    args = parser.parse_args()
    unknown = [n for n in args.names if n not in RUNS]
    if unknown:
        raise SystemExit(f"unknown runs {unknown}; known: {', '.join(RUNS)}")
    record(args.names or list(RUNS))


if __name__ == "__main__":
    main()
