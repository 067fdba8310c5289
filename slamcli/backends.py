"""Loading the heavy compiled libraries: late, clearly, and reproducibly."""

from __future__ import annotations

import logging
import os
import sys
from types import ModuleType

from slamcli.errors import SlamcliError

log = logging.getLogger(__name__)


def import_cv2() -> ModuleType:
    """Import OpenCV with its own logger limited to errors.

    OpenCV prints a ``[ WARN ]`` line on stderr for every image file it cannot open; the
    sources report missing and unreadable images themselves, counted and summarised.
    """
    try:
        import cv2
    except ImportError as exc:
        raise SlamcliError(
            f"OpenCV could not be loaded ({exc})", hint="install the opencv-python-headless package"
        ) from exc
    cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    return cv2


def import_open3d() -> ModuleType:
    """Import Open3D with its kernels on one thread, so results do not depend on thread timing.

    Open3D's parallel reductions (RGB-D odometry, ICP) add partial sums in an order set by
    thread scheduling, and its iterative solvers grow those last-bit differences into
    millimetres of trajectory. Builds that have ``utility.set_max_threads`` (0.20 and later)
    are limited to one thread explicitly: their TBB pool would otherwise size itself from
    whatever CPU affinity the process has when TBB first starts, which another library using
    TBB may already have done. Older builds size their pools from the CPU affinity when the
    library loads, so the process is pinned to one CPU while Open3D loads and released right
    after: Open3D's kernels run on one core and everything else keeps every core.
    """
    if "open3d" in sys.modules:
        return sys.modules["open3d"]
    pinned = None
    if hasattr(os, "sched_getaffinity"):
        pinned = os.sched_getaffinity(0)
        os.sched_setaffinity(0, {min(pinned)})
    try:
        import open3d
    except (ImportError, OSError) as exc:
        raise SlamcliError(
            f"Open3D could not be loaded ({exc})",
            hint="install the open3d-cpu (Linux x86-64) or open3d package; on Debian/Ubuntu it "
            "also needs: apt-get install libusb-1.0-0 libegl1 libgl1",
        ) from exc
    finally:
        if pinned is not None:
            os.sched_setaffinity(0, pinned)
    if hasattr(open3d.utility, "set_max_threads"):
        open3d.utility.set_max_threads(1)
    # Open3D's own warnings (e.g. about its ray-cast range maps) go to the console directly and
    # say nothing a user can act on; slamcli reports what matters itself.
    open3d.utility.set_verbosity_level(open3d.utility.VerbosityLevel.Error)
    log.debug("Open3D %s loaded with single-threaded kernels", open3d.__version__)
    return open3d
