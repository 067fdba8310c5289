"""``slamcli kernels``: compile the numba kernels now instead of on their first use."""

from __future__ import annotations

import time

import typer

from slamcli.cli import render
from slamcli.cli.common import boundary

HELP = """Compile every compiled kernel for this machine now, or load it from numba's cache.

The path search, the car-like planner, feature and stereo matching and the room renderer are \
compiled on their first use after an install (about 40 s in all on 2 cores) and cached; this \
does it ahead, e.g. when building a container image. 'make setup' runs it once per install. \
Prints the seconds each group took.

Example: [bold]slamcli kernels[/]
"""


def register(app: typer.Typer) -> None:
    app.command("kernels", help=HELP, hidden=True)(kernels)


@boundary
def kernels() -> None:
    from slamcli.kernels import KernelGroup, on_compile, warm

    # Each group's line below says what it took; the first-use notice would only repeat it.
    on_compile(None)

    def done(group: KernelGroup, seconds: float) -> None:
        render.note(f"kernels  {group.title:<18} {seconds:6.1f} s")

    t0 = time.perf_counter()
    warm(progress=done)
    render.note(f"kernels  {'all':<18} {time.perf_counter() - t0:6.1f} s")
