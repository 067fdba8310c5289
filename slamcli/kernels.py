"""The compiled kernels: numba functions, compiled on their first call and cached on disk.

Path search, the car-like planner, descriptor matching, stereo matching, bundle adjustment and
pose refinement, and the synthetic room's shading are numba functions with ``cache=True``.
numba compiles each for the argument types of its first call and for this machine's CPU, which
takes from a few seconds (the grid search) to about half a minute (the car-like planner), and
writes the machine code to its cache; every later process loads it from there in milliseconds.

Where the cache lives is numba's choice: ``$NUMBA_CACHE_DIR`` when set; else the
``__pycache__`` folder beside each kernel module when it is writable (a checkout, an editable
install, a virtualenv the user owns); else the user's cache folder (``~/.cache/numba``, or
under ``$XDG_CACHE_HOME``), one per user of a read-only install. A kernel module whose source
changes is compiled again.

:func:`warm` compiles (or loads) every kernel now, by running each group's real code on tiny
inputs, so the argument types are the ones real runs use: ``make setup`` calls it once per
install, so neither the demo, the tests nor their timings pay for compiling.
:func:`on_compile` tells a caller (the command line, which says so on stderr) when a group is
about to be compiled anyway. The visual pipeline's kernels (matching, stereo, pose refinement,
bundle adjustment) take numba from :func:`load_numba`, which builds numba's target cheaply.
"""

from __future__ import annotations

import gc
import importlib.abc
import importlib.machinery
import importlib.util
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from numpy.typing import NDArray

    from slamcli.vision.features import Features

# numpy is imported inside the functions: the command line imports this module at start-up,
# before it knows whether the command needs numpy at all.


@dataclass(frozen=True)
class KernelGroup:
    """Kernels that compile together: the modules one capability calls into.

    Attributes:
        name: short name (``"search"``, ``"car"``, ...).
        title: what the kernels do, as a message names them ("path search").
        modules: the modules defining the group's kernels.
        seconds: about how long compiling the group takes (measured with nothing cached, on
            2 cores), for the message that announces it.
        warm: runs the group's code on tiny inputs, so every kernel is compiled or loaded.
    """

    name: str
    title: str
    modules: tuple[str, ...]
    seconds: float
    warm: Callable[[], None]


def _warm_search() -> None:
    import numpy as np

    from slamcli.planning.search import grid_distances, load_kernels

    load_kernels()
    grid_distances(np.zeros((3, 3), dtype=bool), (1, 1))


def _warm_car() -> None:
    import numpy as np

    from slamcli.planning.car import CarSettings, plan_car
    from slamcli.planning.car_motion import CarLimits
    from slamcli.planning.footprint import Footprint, footprint_cells
    from slamcli.types import OccupancyGrid

    # An 8 x 8 m yard with a wall around it: room to turn, so the search, the analytic
    # expansions, the shortcuts, the clearance and the follower all run, in well under a second
    # once compiled.
    prob = np.zeros((80, 80), dtype=np.float32)
    prob[[0, -1], :] = prob[:, [0, -1]] = 1.0
    grid = OccupancyGrid(prob, 0.1)
    limits = CarLimits(wheelbase_m=0.5, min_turn_radius_m=1.0)
    footprint = Footprint.rectangle(0.8, 0.5)
    for reverse in (True, False):
        settings = CarSettings(footprint, min_turn_radius_m=1.0, reverse=reverse)
        plan_car(grid, (2.0, 2.0, 0.0), (6.0, 6.0, 1.5), settings, limits)
    footprint_cells(footprint, (2.0, 2.0, 0.0), grid)


def _features(image: NDArray[Any]) -> Features:
    from slamcli.vision.features import extract_orb

    return extract_orb(image)


def _texture(shift: int = 0) -> NDArray[Any]:
    """A (120, 160) uint8 grey image with plenty of corners, ``shift`` pixels to the left."""
    import numpy as np

    rng = np.random.default_rng(0)
    blocks = rng.integers(0, 256, size=(15, 21), dtype=np.uint8)
    image = np.kron(blocks, np.ones((8, 8), dtype=np.uint8))
    return np.ascontiguousarray(image[:120, shift : shift + 160])


def _warm_matching() -> None:
    import numpy as np

    from slamcli.vision.matching import match_by_projection, match_ratio_grouped
    from slamcli.vision.vocabulary.files import default_vocabulary

    f = _features(_texture())
    vocabulary = default_vocabulary()
    nodes = vocabulary.nodes(f.descriptors, min(3, vocabulary.levels))
    vocabulary.words(f.descriptors)
    match_ratio_grouped(f.descriptors, nodes, f.descriptors, nodes, 0.8, 50)
    # As tracking calls it: predicted pixels and the frame's (undistorted) keypoints in float64.
    keypoints = f.keypoints.astype(np.float64)
    match_by_projection(
        keypoints,
        f.descriptors,
        np.full(len(f), 3.0),
        keypoints,
        f.descriptors,
        kp_octaves=f.octaves,
        predicted_octaves=f.octaves.astype(np.int64),
        ratio=0.9,
        max_distance=100,
    )


def _warm_stereo() -> None:
    from slamcli.synth.rgbd import camera_for_size
    from slamcli.types import StereoRig
    from slamcli.vision.stereo import StereoSettings, match_stereo

    left, right = _texture(), _texture(shift=4)
    rig = StereoRig(camera_for_size(160, 120), 0.1)
    match_stereo(
        _features(left), _features(right), left, right, rig, StereoSettings(min_depth_m=0.2)
    )


def _warm_adjustment() -> None:
    import numpy as np

    from slamcli.types import PinholeCamera
    from slamcli.vision.bundle_adjustment import bundle_adjust
    from slamcli.vision.pnp import refine_pose_depth

    camera = PinholeCamera(160, 120, 128.0, 128.0, 79.5, 59.5)
    rng = np.random.default_rng(0)
    points = rng.uniform(-1.0, 1.0, (12, 3)) + np.array([0.0, 0.0, 4.0])
    poses = np.stack([np.eye(4), np.eye(4)])
    poses[1, 0, 3] = -0.2
    frame = np.repeat([0, 1], 12)
    point = np.tile(np.arange(12), 2)
    pc = points[point] + poses[frame, :3, 3]
    uv = pc[:, :2] / pc[:, 2:] * [camera.fx, camera.fy] + [camera.cx, camera.cy]
    bundle_adjust(
        camera,
        poses,
        points,
        frame,
        point,
        uv,
        np.ones(24),
        fixed_frames=np.array([True, False]),
        obs_depth=pc[:, 2],
    )
    refine_pose_depth(camera, np.eye(4), uv[:12], points, pc[:12, 2])


def _warm_render() -> None:
    import numpy as np

    from slamcli.synth.rgbd import build_rgbd_world

    world = build_rgbd_world(2, size=(32, 24))
    pose = world.trajectory.world_from_body[0]
    world.render(pose, np.random.default_rng(0))
    world.render_colour(pose)


GROUPS: tuple[KernelGroup, ...] = (
    KernelGroup("search", "path search", ("slamcli.planning._search_kernels",), 5.0, _warm_search),
    KernelGroup(
        "car",
        "car-like planning",
        (
            "slamcli.planning.hybrid_astar",
            "slamcli.planning.footprint",
            "slamcli.planning.curves",
            "slamcli.planning.car_motion",
        ),
        25.0,
        _warm_car,
    ),
    KernelGroup(
        "matching",
        "feature matching",
        ("slamcli.vision._matching_kernels",),
        6.0,
        _warm_matching,
    ),
    KernelGroup(
        "stereo", "stereo matching", ("slamcli.vision._stereo_kernels",), 4.0, _warm_stereo
    ),
    KernelGroup(
        "adjustment",
        "bundle adjustment and pose refinement",
        ("slamcli.vision._ba_kernels", "slamcli.vision._pose_kernels"),
        6.0,
        _warm_adjustment,
    ),
    KernelGroup("render", "room rendering", ("slamcli.synth._render_kernels",), 2.0, _warm_render),
)
"""Every kernel module, in groups; a new module with ``cache=True`` kernels joins one."""


def group_of(module: str) -> KernelGroup | None:
    """The group whose kernels ``module`` defines, or None."""
    return next((g for g in GROUPS if module in g.modules), None)


def warm(
    names: Sequence[str] | None = None, progress: Callable[[KernelGroup, float], None] | None = None
) -> dict[str, float]:
    """Compile, or load from the cache, every kernel of the groups ``names`` (all by default).

    Returns the seconds each group took; ``progress(group, seconds)`` is called after each.

    Raises:
        KeyError: an unknown group name.
    """
    by_name = {g.name: g for g in GROUPS}
    groups = [by_name[n] for n in names] if names is not None else list(GROUPS)
    took: dict[str, float] = {}
    for group in groups:
        t0 = time.perf_counter()
        group.warm()
        took[group.name] = time.perf_counter() - t0
        if progress is not None:
            progress(group, took[group.name])
    return took


def load_adjustment() -> None:
    """Load the bundle adjustment and pose refinement kernels now (compile them if they are not
    cached): a visual run's side process does it as it starts, before its first adjustment."""
    warm(["adjustment"])


_numba_lock = threading.Lock()
_numba_ready = False


def load_numba() -> ModuleType:
    """numba, with its CPU target built: what the first call of any kernel builds otherwise.

    The target is numba's typing and lowering registries: some 100 000 objects that live as
    long as the process. They are made with the cyclic garbage collector paused (it walked
    them again and again while they grew, 50 ms a full pass) and handed straight to its oldest
    generation. Building the target also imports ``scipy.linalg.cython_blas``, numba's way to
    find BLAS, and the ordinary import runs all of ``scipy.linalg`` first (0.15 s: its
    array-API layer imports numpy.testing and numpy.f2py); that one extension module is loaded
    from its file instead, the same module numba would get, without the package around it.
    """
    global _numba_ready
    with _numba_lock:
        if not _numba_ready:
            paused = gc.isenabled()
            gc.disable()
            try:
                _load_cython_blas()
                from numba.core.compiler_lock import global_compiler_lock
                from numba.core.registry import cpu_target

                with global_compiler_lock:
                    cpu_target.target_context.refresh()
            finally:
                if gc.get_freeze_count() == 0:
                    # Straight into the oldest generation, where the collector would move
                    # them after walking them twice; a host's own frozen objects stay so.
                    gc.freeze()
                    gc.unfreeze()
                if paused:
                    gc.enable()
            _numba_ready = True
    import numba

    return numba


def _load_cython_blas() -> None:
    """Import ``scipy.linalg.cython_blas`` without running ``scipy.linalg``'s ``__init__`` (a
    later ``import scipy.linalg`` runs it as usual). The ``scipy`` package itself is imported
    first: it is light, and it finds the BLAS library the module links to. Where the file is
    not where scipy's wheels put it, nothing is done and numba imports it its own way."""
    name = "scipy.linalg.cython_blas"
    if name in sys.modules or "scipy.linalg" in sys.modules:
        return
    try:
        scipy = importlib.import_module("scipy")
    except ImportError:
        return
    found = (
        Path(folder) / "linalg" / f"cython_blas{suffix}"
        for folder in scipy.__path__
        for suffix in importlib.machinery.EXTENSION_SUFFIXES
    )
    path = next((p for p in found if p.is_file()), None)
    spec = importlib.util.spec_from_file_location(name, path) if path is not None else None
    if spec is None or spec.loader is None:
        return
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except Exception:
        del sys.modules[name]


_notify: Callable[[KernelGroup], None] | None = None
_announced: set[str] = set()
_listening = False


def on_compile(callback: Callable[[KernelGroup], None] | None) -> None:
    """Have ``callback(group)`` called when a kernel of ``group`` is about to be compiled
    (nothing in the cache fits this machine and these arguments): once per group and process,
    before the wait. None stops the calls.

    numba is not imported for this: loading it takes about half a second, which commands that
    run no kernel should not pay. The listener joins numba's compile events when numba is
    first imported.
    """
    global _notify
    _notify = callback
    if callback is None or _listening:
        return
    if "numba" in sys.modules:
        _listen()
    elif not any(isinstance(f, _AfterImport) for f in sys.meta_path):
        sys.meta_path.insert(0, _AfterImport("numba", _listen))


def _listen() -> None:
    """Register the compile listener with numba (once)."""
    global _listening
    if _listening:
        return
    _listening = True
    from numba.core import event

    class Listener(event.Listener):
        def on_start(self, ev: Any) -> None:
            group = group_of(ev.data["dispatcher"].py_func.__module__)
            if group is None or group.name in _announced or _notify is None:
                return
            _announced.add(group.name)
            _notify(group)

        def on_end(self, ev: Any) -> None:
            return None

    event.register("numba:compile", Listener())


class _AfterImport(importlib.abc.MetaPathFinder):
    """Runs ``then()`` right after the module ``name`` is first imported, by whoever imports
    it; then leaves the import system as it found it."""

    def __init__(self, name: str, then: Callable[[], None]) -> None:
        self.name = name
        self.then = then

    def find_spec(
        self, fullname: str, path: Sequence[str] | None, target: ModuleType | None = None
    ) -> importlib.machinery.ModuleSpec | None:
        if fullname != self.name:
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(fullname)
        if spec is None or spec.loader is None:
            return spec
        loader, then = spec.loader, self.then
        load = loader.exec_module

        def exec_module(module: ModuleType) -> None:
            load(module)
            then()

        loader.exec_module = exec_module  # type: ignore[method-assign]
        return spec


__all__ = [
    "GROUPS",
    "KernelGroup",
    "group_of",
    "load_adjustment",
    "load_numba",
    "on_compile",
    "warm",
]
