"""Run a command and measure its own CPU time and peak RSS.

On Linux a child's ``ru_maxrss`` starts from its parent's resident set at the fork (the copied
address space is counted, exec or not), so a command forked straight from a test worker that
has run pipelines in-process reports the worker's size, not its own. The command is therefore
started by a small fresh Python process, which forks it, waits for it with ``wait4`` and prints
its exit code, CPU seconds and peak RSS on the last line of the output.
"""

from __future__ import annotations

import subprocess
import sys
from typing import Any

MARK = "__measured_rusage__"

_LAUNCHER = f"""
import os, subprocess, sys
proc = subprocess.Popen(sys.argv[1:])
_, status, usage = os.wait4(proc.pid, 0)
print("\\n{MARK}", os.waitstatus_to_exitcode(status), repr(usage.ru_utime + usage.ru_stime),
      usage.ru_maxrss, flush=True)
"""


def run_measured(argv: list[str], **popen: Any) -> tuple[int, str, float, float]:
    """(exit code, stdout and stderr, CPU seconds, peak RSS in MB) of the command ``argv``."""
    proc = subprocess.Popen(
        [sys.executable, "-c", _LAUNCHER, *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        **popen,
    )
    assert proc.stdout is not None
    output = proc.stdout.read().decode(errors="replace")
    proc.wait()
    text, _, last = output.rstrip("\n").rpartition("\n")
    mark, code, seconds, rss_kb = last.split()
    assert mark == MARK, output
    return int(code), text, float(seconds), int(rss_kb) / 1024
