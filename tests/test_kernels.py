"""The compiled kernels: every one is in a group that ``warm()`` compiles, and a command that
compiles one says so on stderr, once."""

from __future__ import annotations

import importlib
import json
import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from slamcli import kernels
from slamcli.formats.occupancy.npz import write_map_npz
from slamcli.types import OccupancyGrid

REPO = Path(__file__).resolve().parents[1]
SLAMCLI = Path(sys.executable).parent / "slamcli"


_CACHED_KERNEL = re.compile(r"^@numba\.njit\(.*\bcache=True", re.MULTILINE)


def _modules_with_cached_kernels() -> set[str]:
    """Every slamcli module whose source declares a numba function cached on disk."""
    found = set()
    for path in (REPO / "slamcli").rglob("*.py"):
        if _CACHED_KERNEL.search(path.read_text(encoding="utf-8")):
            found.add(".".join(path.relative_to(REPO).with_suffix("").parts))
    return found


def test_every_kernel_module_is_in_one_group() -> None:
    grouped = [m for g in kernels.GROUPS for m in g.modules]
    assert len(grouped) == len(set(grouped)), "a module in two groups"
    assert set(grouped) == _modules_with_cached_kernels()
    for module in grouped:
        group = kernels.group_of(module)
        assert group is not None and module in group.modules


# Run in a process of its own: kernels the other tests of this process compiled must not count.
_UNREACHED = """
import importlib, json, types
from numba.core.registry import CPUDispatcher
from slamcli import kernels

kernels.warm()
dispatchers = {}
for group in kernels.GROUPS:
    for module in group.modules:
        for name, obj in vars(importlib.import_module(module)).items():
            if isinstance(obj, CPUDispatcher) and obj.py_func.__module__ == module:
                dispatchers[f"{module}.{name}"] = obj


def called(code):
    for name in code.co_names:
        yield name
    for const in code.co_consts:
        if isinstance(const, types.CodeType):
            yield from called(const)


# A kernel that only other kernels call is compiled into them, and loaded with them from the
# cache without a signature of its own: it counts as reached through them.
reached = {key for key, d in dispatchers.items() if d.signatures}
todo = list(reached)
while todo:
    d = dispatchers[todo.pop()]
    for name in called(d.py_func.__code__):
        callee = d.py_func.__globals__.get(name)
        if isinstance(callee, CPUDispatcher):
            key = f"{callee.py_func.__module__}.{callee.__name__}"
            if key in dispatchers and key not in reached:
                reached.add(key)
                todo.append(key)
print(json.dumps(sorted(set(dispatchers) - reached)))
"""


def test_warm_compiles_every_kernel() -> None:
    """After ``warm()`` every kernel of every group has been compiled or loaded, directly or
    inside a kernel that calls it."""
    run = subprocess.run(
        [sys.executable, "-c", _UNREACHED], capture_output=True, text=True, check=False
    )
    assert run.returncode == 0, run.stderr[-3000:]
    assert json.loads(run.stdout.splitlines()[-1]) == []


def test_on_compile_tells_once_per_group_and_not_from_the_cache(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The callback hears of a compile (a cache miss) once per group; a kernel loaded from
    numba's cache is not announced."""
    from numba.core import config

    source = tmp_path / "tiny_kernels.py"
    source.write_text(
        textwrap.dedent(
            """
            import numba

            @numba.njit(cache=True)
            def twice(x):
                return 2 * x

            @numba.njit(cache=True)
            def thrice(x):
                return 3 * x
            """
        ),
        encoding="utf-8",
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(config, "CACHE_DIR", str(tmp_path / "cache"))
    group = kernels.KernelGroup("tiny", "tiny", ("tiny_kernels",), 1.0, lambda: None)
    monkeypatch.setattr(kernels, "GROUPS", (*kernels.GROUPS, group))
    monkeypatch.setattr(kernels, "_announced", set())
    heard: list[str] = []
    kernels.on_compile(lambda g: heard.append(g.name))
    try:
        module = importlib.import_module("tiny_kernels")
        assert module.twice(2) == 4
        assert module.thrice(2) == 6
        assert heard == ["tiny"]
        # A new process: nothing announced yet, the machine code in the cache.
        kernels._announced.clear()
        del sys.modules["tiny_kernels"]
        module = importlib.import_module("tiny_kernels")
        assert module.twice(3) == 6
        assert module.thrice(3) == 9
        assert heard == ["tiny"]
        assert module.twice.stats.cache_hits
    finally:
        kernels.on_compile(None)
        sys.modules.pop("tiny_kernels", None)


def test_a_command_says_once_that_it_compiles(tmp_path: Path) -> None:
    """The first ``slamcli plan`` with nothing cached prints one line saying the path search is
    being compiled; the second, reading numba's cache, prints none. (About 5 s of compiling:
    the grid search is the smallest group a command compiles alone.)"""
    prob = np.zeros((5, 5), dtype=np.float32)
    write_map_npz(tmp_path / "map.npz", OccupancyGrid(prob, 1.0))
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "numba"), NO_COLOR="1")
    command = [str(SLAMCLI), "plan", "map.npz", "--start", "0.5,0.5", "--goal", "4.5,4.5"]
    lines = []
    for k in (1, 2):
        run = subprocess.run(
            [*command, "--robot-radius", "0", "--out", f"plan{k}"],
            cwd=tmp_path,
            env=env,
            capture_output=True,
            text=True,
            check=False,
        )
        assert run.returncode == 0, run.stderr
        lines.append([ln for ln in run.stderr.splitlines() if "compiling" in ln])
    assert lines == [
        ["slamcli: compiling the path search kernels for this machine, once (about 5 s)"],
        [],
    ]


def test_load_numba_finds_blas_without_importing_scipy_linalg() -> None:
    """numba's CPU target looks for BLAS in ``scipy.linalg.cython_blas``: load_numba gives it
    that module without running ``scipy.linalg``, which a later import still runs as usual."""
    code = textwrap.dedent(
        """
        import sys
        from slamcli.kernels import load_numba
        load_numba()
        from numba.np.arraymath import _HAVE_BLAS
        before = "scipy.linalg" in sys.modules
        import numpy as np
        import scipy.linalg
        from scipy.linalg import cython_blas
        solved = scipy.linalg.solve(np.eye(2), np.ones(2)).tolist()
        print(_HAVE_BLAS, before, cython_blas is sys.modules["scipy.linalg.cython_blas"], solved)
        """
    )
    run = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO
    )
    assert run.stdout.split() == ["True", "False", "True", "[1.0,", "1.0]"]
