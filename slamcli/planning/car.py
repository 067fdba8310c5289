"""``plan_car()``: a car-like robot's path from a start pose to a goal pose.

Steps, each timed in ``timings_ms``:

1. **Free space.** Occupied cells, and unknown ones unless ``unknown="free"``, are blocked;
   nothing is inflated: the footprint polygon itself is tested against the cells
   (:mod:`slamcli.planning.footprint`).
2. **Heuristic.** The exact grid distance to the goal (:func:`~slamcli.planning.search.
   grid_distances`) over the cells the footprint's inscribed circle may enter.
3. **Search.** Hybrid-A* (:mod:`slamcli.planning.hybrid_astar`) with Reeds-Shepp (or, without
   reversing, Dubins) curves to the goal.
4. **Smoothing.** Analytic shortcuts that keep the curvature within ``1 / min_turn_radius`` and
   the clearance the search path had (up to :data:`SMOOTH_MARGIN_M`).
5. **Check.** Every pose of the final path, sampled at most half a cell apart, is tested with
   the exact footprint test; a failure is an internal error, never a silent result.
6. **Timing and tracking.** A speed profile that stops at each gear change
   (:mod:`slamcli.planning.car_motion`) and a simulated bicycle-model robot following it.

Poses are ``(x, y, yaw)`` in the map's world frame (m, rad); the map's origin yaw is honoured.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from slamcli.errors import ConfigError, MapError, NoPathError
from slamcli.planning.car_motion import (
    CarLimits,
    CarProfile,
    simulate_bicycle,
    time_parameterise_car,
)
from slamcli.planning.costmap import (
    CENTRING_RADIUS_M,
    OCCUPIED_THRESH,
    centring_cost,
    clearance_ratio,
    nearest_free_cell,
    uv_to_world,
    world_to_uv,
)
from slamcli.planning.footprint import Footprint, FootprintChecker
from slamcli.planning.steering import (
    FULL_LOCK_DISTANCE_M,
    curvature_rate,
    pose_curvatures,
    steered_path,
)
from slamcli.planning.tracker import TrackerSettings, TrackingResult
from slamcli.types import OccupancyGrid

SMOOTH_MARGIN_M = 0.10
"""Shortcuts keep at least this clearance wherever the search path had it, metres."""

CLEARANCE_LADDER_M = (0.10, 0.05, 0.02)
"""Margins the search tries to keep around the footprint, largest first, metres."""

N_HEADINGS = 72
"""Heading bins of the lattice (5 degrees)."""

COST_PENALTY = 8.0
"""Default weight of the centring cost (see :class:`CarSettings`)."""

MAX_PLANNING_TIME_S = 5.0
"""Default time budget of the search, seconds (Nav2's ``max_planning_time``)."""

FIRST_SEARCH_SHARE = 0.6
"""Share of the time budget the full search gets before a greedy one takes over."""

GREED = 3.0
"""Heuristic weight of the greedy search that runs when the full one runs out of time."""


@dataclass(frozen=True)
class CarSettings:
    """The car and the search.

    Attributes:
        footprint: the robot's outline in its body frame (x forward, y left), metres.
        min_turn_radius_m: the tightest turn of the reference point, metres.
        reverse: whether the robot may drive backwards (Reeds-Shepp) or not (Dubins).
        unknown: ``"blocked"`` or ``"free"``: how unknown cells count.
        bin_m: lattice bin size in metres; None = max(resolution, radius / 8).
        step_m: primitive arc length; None = 1.5 bins.
        n_steer: curvatures per gear.
        reverse_weight: cost factor of reversing (2, as Nav2's Smac planner).
        switch_penalty_m: cost of a gear change, metres.
        max_expanded: expansion cap of the search.
        cost_penalty: weight of the centring cost (:func:`~slamcli.planning.costmap.
            centring_cost`): a metre driven where the cost is c costs ``1 + cost_penalty * c``
            metres. 0 gives the shortest path.
        inflation_radius_m: how far around a point the centring cost looks for the middle of
            the free space, metres.
        full_lock_distance_m: the shortest travel over which the steering may go from
            straight ahead to full lock: the curvature changes by at most
            ``1 / (min_turn_radius_m * full_lock_distance_m)`` per metre
            (:mod:`slamcli.planning.steering`); None keeps the arcs and lines, whose
            curvature jumps.
        max_planning_time_s: the search's time budget, seconds (None: no limit), from its
            start (after the free space and the heuristic); see :func:`_search`.
    """

    footprint: Footprint
    min_turn_radius_m: float = 1.2
    reverse: bool = True
    unknown: str = "blocked"
    bin_m: float | None = None
    step_m: float | None = None
    n_steer: int = 5
    reverse_weight: float = 2.0
    switch_penalty_m: float = 1.0
    max_expanded: int = 3_000_000
    cost_penalty: float = COST_PENALTY
    inflation_radius_m: float = CENTRING_RADIUS_M
    max_planning_time_s: float | None = MAX_PLANNING_TIME_S
    full_lock_distance_m: float | None = FULL_LOCK_DISTANCE_M

    def checked(self) -> CarSettings:
        if not (math.isfinite(self.min_turn_radius_m) and self.min_turn_radius_m > 0):
            raise ConfigError(
                f"--min-turn-radius must be a positive number of metres, got "
                f"{self.min_turn_radius_m!r}",
                hint="for example --min-turn-radius 1.2",
            )
        if not (math.isfinite(self.reverse_weight) and self.reverse_weight >= 1.0):
            raise ConfigError(
                f"--reverse-penalty must be a number >= 1, got {self.reverse_weight!r}",
                hint="1 gives the shortest path; larger values prefer driving forwards",
            )
        if not (math.isfinite(self.cost_penalty) and self.cost_penalty >= 0.0):
            raise ConfigError(
                f"--cost-penalty must be a number >= 0, got {self.cost_penalty!r}",
                hint="0 gives the shortest path; larger values keep the path nearer the middle "
                "of the free space",
            )
        if not (math.isfinite(self.inflation_radius_m) and self.inflation_radius_m > 0.0):
            raise ConfigError(
                f"--inflation-radius must be a positive number of metres, got "
                f"{self.inflation_radius_m!r}",
                hint=f"for example --inflation-radius {CENTRING_RADIUS_M}",
            )
        d = self.full_lock_distance_m
        if d is not None and not (math.isfinite(d) and d > 0.0):
            raise ConfigError(
                f"--full-lock-distance must be a positive number of metres, got {d!r}",
                hint=f"for example --full-lock-distance {FULL_LOCK_DISTANCE_M:g}; 0 keeps the "
                "arcs and lines",
            )
        t = self.max_planning_time_s
        if t is not None and not (math.isfinite(t) and t > 0.0):
            raise ConfigError(
                f"--max-planning-time must be a positive number of seconds, got {t!r}",
                hint=f"for example --max-planning-time {MAX_PLANNING_TIME_S:g}",
            )
        if self.unknown not in ("blocked", "free"):
            raise ConfigError(
                f"--unknown must be 'free' or 'blocked', got {self.unknown!r}",
                hint="--unknown blocked keeps the robot in mapped free space",
            )
        return self


@dataclass
class CarPlanResult:
    """Everything :func:`plan_car` produced; world frame, metres and radians.

    Attributes:
        start, goal: the poses asked for.
        poses: (N, 3) ``x, y, yaw`` of the final path, at most half a cell apart.
        direction: (N,) +1 forward / -1 reverse, the gear of the motion leaving each pose.
        curvature: (N,) signed curvature (1/m) of the motion leaving each pose.
        search_poses: (K, 3) the lattice nodes of the search path, before smoothing.
        length_m, reversals, min_clearance_m, max_curvature: the path's figures.
        clearance_ratio: (median, 10th percentile) over the poses of the clearance ratio of
            their cells (:func:`~slamcli.planning.costmap.clearance_ratio`, over
            ``inflation_radius_m``): 1 on the middle line of the free space, 0 at a wall.
        max_curvature_rate: the largest change of curvature per metre between consecutive
            poses of one gear (1/m², from the poses' headings and spacing);
            curvature_rate_limit: the limit the path was made for (None: not limited).
        profile, trajectory, tracking: the timed path, sampled every ``dt_s``, and the
            simulated robot.
        expanded: search nodes expanded.
        timings_ms: per stage.
        warnings: what the user should know of how the path was found (a search cut short
            by ``max_planning_time_s``).
    """

    start: tuple[float, float, float]
    goal: tuple[float, float, float]
    grid: OccupancyGrid
    blocked: NDArray[np.bool_]
    settings: CarSettings
    limits: CarLimits
    poses: NDArray[np.float64]
    direction: NDArray[np.int8]
    curvature: NDArray[np.float64]
    search_poses: NDArray[np.float64]
    length_m: float
    reversals: int
    min_clearance_m: float
    clearance_ratio: tuple[float, float]
    max_curvature_rate: float
    curvature_rate_limit: float | None
    max_curvature: float
    profile: CarProfile
    trajectory: NDArray[np.float64]
    tracking: TrackingResult
    expanded: int
    timings_ms: dict[str, float] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)

    @property
    def goal_error(self) -> tuple[float, float]:
        """(metres, radians) between the path's last pose and the goal."""
        end = self.poses[-1]
        d = math.hypot(end[0] - self.goal[0], end[1] - self.goal[1])
        a = abs((end[2] - self.goal[2] + math.pi) % (2 * math.pi) - math.pi)
        return d, a


def _ms(t: float) -> float:
    return round((time.perf_counter() - t) * 1000.0, 3)


def car_blocked(grid: OccupancyGrid, unknown: str) -> NDArray[np.bool_]:
    """(H, W) cells a car's footprint may not touch: occupied, and unknown unless ``free``."""
    prob = np.asarray(grid.prob, dtype=np.float64)
    nan = np.isnan(prob)
    blocked = np.zeros(prob.shape, dtype=bool)
    np.greater_equal(prob, OCCUPIED_THRESH, out=blocked, where=~nan)
    if unknown == "blocked":
        blocked |= nan
    return blocked


def _to_grid(grid: OccupancyGrid, pose: tuple[float, float, float]) -> tuple[float, float, float]:
    u, v = world_to_uv(grid, pose[:2])
    return float(u), float(v), float(pose[2]) - float(grid.origin_xy_yaw[2])


def _check_pose(
    grid: OccupancyGrid,
    checker: FootprintChecker,
    blocked: NDArray[np.bool_],
    pose: tuple[float, float, float],
    flag: str,
    unknown: str,
) -> None:
    """MapError naming the nearest free cell when the footprint at ``pose`` touches a blocked
    cell (or leaves the map)."""
    if bool(checker.free(np.asarray([pose], dtype=np.float64))[0]):
        return
    h, w = blocked.shape
    u, v = world_to_uv(grid, pose[:2])
    cell = (min(max(int(v), 0), h - 1), min(max(int(u), 0), w - 1))
    inside = 0 <= u < w and 0 <= v < h
    # A cell whose centre is at least the circumradius from every blocked cell takes the
    # footprint at any heading.
    res = float(grid.resolution_m)
    from scipy.ndimage import distance_transform_edt

    room = distance_transform_edt(~blocked) * res
    near = nearest_free_cell(room < checker.footprint.circumradius_m + res, cell)
    where = "outside the map" if not inside else "touching an obstacle or unknown space"
    hint = "choose a pose in open space"
    if near is not None:
        x, y = uv_to_world(grid, [near[1] + 0.5, near[0] + 0.5])
        hint = f"move {flag} to ({x:.2f}, {y:.2f}), where the footprint fits at any heading"
    if unknown == "blocked" and inside:
        hint += ", or pass --unknown free if the footprint only overlaps unknown cells"
    raise MapError(
        f"{flag} ({pose[0]:g}, {pose[1]:g}, yaw {math.degrees(pose[2]):.1f} deg): the footprint "
        f"is {where}",
        hint=hint,
    )


@dataclass
class _Problem:
    """One planning query in the grid frame (cells, radians): what every step shares."""

    grid: OccupancyGrid
    settings: CarSettings
    blocked: NDArray[np.bool_]
    checker: FootprintChecker
    margin: FootprintChecker
    start: tuple[float, float, float]
    goal: tuple[float, float, float]
    holonomic: NDArray[np.float64]
    cost: NDArray[np.float64] | None
    ratio: NDArray[np.float64]
    radius: float
    step: float
    bin_size: float

    def search(
        self,
        reverse: bool,
        cap: int,
        test: FootprintChecker | None = None,
        deadline: float = math.inf,
        greed: float = 1.0,
    ) -> Any:
        from slamcli.planning.hybrid_astar import lattice_search

        res = float(self.grid.resolution_m)
        return lattice_search(
            test or self.checker,
            self.holonomic,
            self.start,
            self.goal,
            cost=self.cost,
            radius=self.radius,
            step=self.step,
            bin_size=self.bin_size,
            n_steer=self.settings.n_steer,
            n_headings=N_HEADINGS,
            reverse=reverse,
            reverse_weight=self.settings.reverse_weight,
            switch_penalty=self.settings.switch_penalty_m / res,
            max_expanded=cap,
            deadline=deadline,
            greed=greed,
        )


def plan_car(
    grid: OccupancyGrid,
    start: tuple[float, float, float],
    goal: tuple[float, float, float],
    settings: CarSettings,
    limits: CarLimits,
    *,
    dt_s: float = 0.1,
    tracker: TrackerSettings | None = None,
) -> CarPlanResult:
    """Plan, smooth, check, time and track a car-like path (see the module doc).

    Raises MapError when the footprint at the start or goal collides (naming a free place
    nearby), NoPathError when no path exists (saying whether reversing would find one),
    ConfigError for a bad setting.
    """
    from slamcli.planning.search import load_kernels

    settings = settings.checked()
    timings: dict[str, float] = {}
    tk = time.perf_counter()
    load_kernels()
    timings["kernels"] = _ms(tk)
    t0 = time.perf_counter()
    blocked = car_blocked(grid, settings.unknown)
    checker = FootprintChecker(blocked, grid, settings.footprint)
    margin = FootprintChecker(
        blocked, grid, settings.footprint.offset(SMOOTH_MARGIN_M), dist=checker.dist
    )
    timings["costmap"] = _ms(t0)
    _check_pose(grid, checker, blocked, start, "--start", settings.unknown)
    _check_pose(grid, checker, blocked, goal, "--goal", settings.unknown)
    turn = abs((goal[2] - start[2] + math.pi) % (2 * math.pi) - math.pi)
    if math.hypot(goal[0] - start[0], goal[1] - start[1]) < 1e-6 and turn < 1e-6:
        raise ConfigError(
            "--start and --goal are the same pose: there is nothing to plan",
            hint="give a goal position or heading that differs from the start",
        )
    t1 = time.perf_counter()
    problem = _problem(grid, settings, blocked, checker, margin, start, goal)
    timings["heuristic"] = _ms(t1)
    t2 = time.perf_counter()
    warnings: list[str] = []
    budget = settings.max_planning_time_s
    deadline = math.inf if budget is None else t2 + budget
    found = _search(problem, np.asarray([start, goal], dtype=np.float64), t2, deadline, warnings)
    timings["search"] = _ms(t2)
    t3 = time.perf_counter()
    nodes = np.vstack((found.nodes, np.asarray([problem.goal])))
    poses_g, gears, curv = _smooth(problem, found, nodes)
    timings["smooth"] = _ms(t3)
    t4 = time.perf_counter()
    poses, curvature = _checked_world_path(problem, poses_g, curv)
    timings["check"] = _ms(t4)
    t45 = time.perf_counter()
    steering = _steer(problem, poses, gears, curvature, warnings)
    poses, gears, curvature = steering.poses, steering.direction, steering.curvature
    timings["steering"] = _ms(t45)
    clearance = checker.clearance(poses)
    h, w = blocked.shape
    uv = world_to_uv(grid, poses[:, :2])
    rows = np.clip(uv[:, 1].astype(np.int64), 0, h - 1)
    cols = np.clip(uv[:, 0].astype(np.int64), 0, w - 1)
    ratio = problem.ratio[rows, cols]
    rates = _curvature_rates(poses, gears)
    t5 = time.perf_counter()
    profile = time_parameterise_car(poses, gears, curvature, limits)
    trajectory = profile.sample_every(dt_s)
    timings["trajectory"] = _ms(t5)
    t6 = time.perf_counter()
    tracking = simulate_bicycle(profile, limits, tracker or TrackerSettings())
    timings["simulate"] = _ms(t6)
    seg = np.diff(poses[:, :2], axis=0)
    return CarPlanResult(
        start=start,
        goal=goal,
        grid=grid,
        blocked=blocked,
        settings=settings,
        limits=limits,
        poses=poses,
        direction=gears,
        curvature=curvature,
        search_poses=np.column_stack(
            (uv_to_world(grid, nodes[:, :2]), nodes[:, 2] + float(grid.origin_xy_yaw[2]))
        ),
        length_m=float(np.hypot(seg[:, 0], seg[:, 1]).sum()),
        reversals=int(np.count_nonzero(np.diff(gears[:-1].astype(np.int64)) != 0)),
        min_clearance_m=float(clearance.min()),
        clearance_ratio=(float(np.median(ratio)), float(np.percentile(ratio, 10))),
        max_curvature_rate=float(rates.max()) if len(rates) else 0.0,
        curvature_rate_limit=(
            None
            if settings.full_lock_distance_m is None
            else curvature_rate(settings.min_turn_radius_m, settings.full_lock_distance_m)
        ),
        max_curvature=float(np.abs(curvature).max()),
        profile=profile,
        trajectory=trajectory,
        tracking=tracking,
        expanded=found.expanded,
        timings_ms=timings,
        warnings=warnings,
    )


def _problem(
    grid: OccupancyGrid,
    settings: CarSettings,
    blocked: NDArray[np.bool_],
    checker: FootprintChecker,
    margin: FootprintChecker,
    start: tuple[float, float, float],
    goal: tuple[float, float, float],
) -> _Problem:
    """The query in grid units, with its holonomic heuristic: the exact grid distance to the
    goal over the cells where the reference point can be at some heading."""
    from slamcli.planning.search import grid_distances

    res = float(grid.resolution_m)
    # Cells where the reference point collides at any heading (the inscribed circle meets a
    # blocked cell wherever in the cell it lies) are out of the heuristic's grid.
    inscribed = checker.dist + math.sqrt(2.0) < checker.r_in
    gs = _to_grid(grid, goal)
    h, w = blocked.shape
    goal_cell = (min(max(int(gs[1]), 0), h - 1), min(max(int(gs[0]), 0), w - 1))
    bin_m = settings.bin_m or max(res, settings.min_turn_radius_m / 8.0)
    ratio = clearance_ratio(blocked, res, settings.inflation_radius_m)
    cost = None
    if settings.cost_penalty > 0.0:
        cost = settings.cost_penalty * centring_cost(ratio)
    return _Problem(
        grid=grid,
        settings=settings,
        blocked=blocked,
        checker=checker,
        margin=margin,
        start=_to_grid(grid, start),
        goal=gs,
        holonomic=grid_distances(blocked | inscribed, goal_cell, extra_cost=cost),
        cost=cost,
        ratio=ratio,
        radius=settings.min_turn_radius_m / res,
        step=(settings.step_m or 1.5 * bin_m) / res,
        bin_size=bin_m / res,
    )


def _search(
    problem: _Problem,
    ends: NDArray[np.float64],
    started: float,
    deadline: float,
    warnings: list[str],
) -> Any:
    """The lattice path, then the same search with the footprint grown by a margin (the largest
    of :data:`CLEARANCE_LADDER_M` that works within a few times the first search's effort), so
    the path keeps that clearance everywhere when the map allows it.

    With a deadline, the full search gets :data:`FIRST_SEARCH_SHARE` of the time; when it runs
    out, a greedy search (heuristic weighed by :data:`GREED`) gets the rest, and its path comes
    with a warning; a margin search still running at the deadline is dropped, with a warning.
    """
    from slamcli.planning.hybrid_astar import FOUND, LIMIT, TIMEOUT

    settings = problem.settings
    first = started + FIRST_SEARCH_SHARE * (deadline - started)
    found = problem.search(settings.reverse, settings.max_expanded, deadline=first)
    if found.status == TIMEOUT:
        greedy = problem.search(
            settings.reverse, settings.max_expanded, deadline=deadline, greed=GREED
        )
        spent = found.expanded + greedy.expanded
        budget = deadline - started
        if greedy.status != FOUND:
            if greedy.status == TIMEOUT:
                raise NoPathError(
                    f"no path found within --max-planning-time {budget:g} s ({spent} search "
                    "states)",
                    hint="raise --max-planning-time, or try a goal in more open space",
                )
            _no_path(greedy, settings, problem.search, LIMIT, FOUND)
        warnings.append(
            f"the full search ran out of --max-planning-time ({budget:g} s) after "
            f"{found.expanded} states; this path comes from a greedy search and may be up to "
            f"{GREED:g} times as costly as the best (raise --max-planning-time for that)"
        )
        return dataclasses.replace(greedy, expanded=spent)
    if found.status != FOUND:
        _no_path(found, settings, problem.search, LIMIT, FOUND)
    spent = found.expanded
    for margin in CLEARANCE_LADDER_M:
        wider = FootprintChecker(
            problem.blocked,
            problem.grid,
            settings.footprint.offset(margin),
            dist=problem.checker.dist,
        )
        if not wider.free(ends).all():
            continue
        wide = problem.search(
            settings.reverse, 4 * found.expanded + 20_000, wider, deadline=deadline
        )
        spent += wide.expanded
        if wide.status == TIMEOUT:
            warnings.append(
                f"--max-planning-time ran out while looking for a path with {margin:g} m of "
                "margin around the footprint; this one keeps only the footprint itself clear"
            )
            break
        if wide.status == FOUND:
            found = wide
            break
    return dataclasses.replace(found, expanded=spent)


def _smooth(
    problem: _Problem, found: Any, nodes: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.int8], NDArray[np.float64]]:
    """Analytic shortcuts over the lattice path (``nodes``: its poses and the goal); the final
    path's grid poses, gears and curvatures (1/cells)."""
    from slamcli.planning.hybrid_astar import (
        pieces_cost,
        sample_pieces,
        segment_curvatures,
        shortcut_path,
    )

    # Piece a reaches node a: a lattice primitive, or (the last) the analytic tail.
    pieces: list[tuple[NDArray[np.float64], NDArray[np.float64]]] = [(np.zeros(0), np.zeros(0))]
    for a in range(1, len(found.nodes)):
        pieces.append(
            (np.array([found.curvature[a]]), np.array([found.direction[a] * problem.step]))
        )
    pieces.append((segment_curvatures(found.tail_kinds, problem.radius), found.tail_lengths))
    piece_clear = np.ones(len(nodes), dtype=bool)
    piece_gears = np.zeros((len(nodes), 3), dtype=np.int64)
    for a in range(1, len(nodes)):
        p = sample_pieces(nodes[a - 1], *pieces[a], 0.5)[0]
        piece_clear[a] = bool(problem.margin.free_uv(p).all()) if len(p) else True
        signs = np.sign(pieces[a][1][pieces[a][1] != 0]).astype(np.int64)
        if len(signs):
            piece_gears[a] = (signs[0], signs[-1], np.count_nonzero(np.diff(signs)))
    weight = problem.settings.reverse_weight
    if problem.cost is None and weight == 1.0:
        piece_len = np.array([float(np.abs(ln).sum()) for _, ln in pieces])
    else:
        piece_len = np.array(
            [0.0]
            + [
                pieces_cost(problem.cost, nodes[a - 1], *pieces[a], weight)
                for a in range(1, len(nodes))
            ]
        )
    keep = shortcut_path(
        problem.checker,
        problem.margin,
        nodes,
        piece_len,
        piece_clear,
        piece_gears,
        radius=problem.radius,
        reverse=problem.settings.reverse,
        min_piece=0.5 * problem.step,
        cost=problem.cost,
        reverse_weight=weight,
    )
    return _assemble(nodes, pieces, keep, problem.radius, problem.settings.reverse)


def _steer(
    problem: _Problem,
    poses: NDArray[np.float64],
    gears: NDArray[np.int8],
    curvature: NDArray[np.float64],
    warnings: list[str],
) -> Any:
    """The path with continuous steering (:mod:`slamcli.planning.steering`), or as it is when
    ``full_lock_distance_m`` is None; a warning for the gear runs that kept their jumps."""
    from slamcli.planning.steering import SteeredPath

    settings = problem.settings
    if settings.full_lock_distance_m is None:
        return SteeredPath(poses, gears, curvature, 0, 0)
    radius = settings.min_turn_radius_m
    steered = steered_path(
        poses,
        gears,
        curvature,
        kappa_max=1.0 / radius,
        rate=curvature_rate(radius, settings.full_lock_distance_m),
        ds=0.45 * float(problem.grid.resolution_m),
        free=problem.checker.free,
    )
    if steered.kept_runs:
        warnings.append(
            f"{steered.kept_runs} of {steered.runs} stretches between gear changes keep "
            "steps in their steering: with ramps they would touch an obstacle or leave "
            "the turn radius"
        )
    return steered


def _curvature_rates(poses: NDArray[np.float64], gears: NDArray[np.int8]) -> NDArray[np.float64]:
    """|change of curvature| per metre between consecutive motions of one gear, 1/m²,
    measured from the poses."""
    kappa, arcs = pose_curvatures(poses)
    same = gears[1:-1] == gears[:-2]
    mid = 0.5 * (arcs[1:] + arcs[:-1])
    ok = same & (mid > 1e-9)
    return np.abs(np.diff(kappa))[ok] / mid[ok]


def _checked_world_path(
    problem: _Problem, poses_g: NDArray[np.float64], curv: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The path in the world (poses, curvature 1/m), every pose tested with the exact
    footprint test: a failure is an error, never a silent result."""
    grid = problem.grid
    poses = np.empty_like(poses_g)
    poses[:, :2] = uv_to_world(grid, poses_g[:, :2])
    poses[:, 2] = np.angle(np.exp(1j * (poses_g[:, 2] + float(grid.origin_xy_yaw[2]))))
    free = problem.checker.free(poses)
    if not free.all():
        bad = int(np.flatnonzero(~free)[0])
        raise NoPathError(
            f"internal check failed: pose {bad} of the path ({poses[bad, 0]:.3f}, "
            f"{poses[bad, 1]:.3f}) touches a blocked cell",
            hint="report this with the map and the command",
        )
    return poses, curv / float(grid.resolution_m)


def _assemble(
    nodes: NDArray[np.float64],
    pieces: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
    keep: NDArray[np.int64],
    radius: float,
    reverse: bool,
) -> tuple[NDArray[np.float64], NDArray[np.int8], NDArray[np.float64]]:
    """The final path's poses (grid frame), gears and curvatures (1/cells), start to goal:
    kept pieces as they were, shortcuts as the shortest analytic curve."""
    from slamcli.planning.curves import shortest_curve
    from slamcli.planning.hybrid_astar import _L, _R, _S, sample_pieces, segment_curvatures

    codes = {"S": _S, "L": _L, "R": _R}
    poses = [nodes[:1]]
    gears: list[NDArray[np.int8]] = []
    curvs: list[NDArray[np.float64]] = []
    for i, j in itertools.pairwise(keep):
        if j == i + 1:
            kappas, lengths = pieces[j]
        else:
            curve = shortest_curve(tuple(nodes[i]), tuple(nodes[j]), radius, reverse=reverse)
            kappas = segment_curvatures([codes[k] for k in curve.kinds], radius)
            lengths = np.asarray(curve.lengths, dtype=np.float64)
        p, g, c = sample_pieces(nodes[i], kappas, lengths, 0.5)
        poses.append(p)
        gears.append(g)
        curvs.append(c)
    all_poses = np.vstack(poses)
    # A sample carries the gear/curvature of the piece it ends; the motion leaving a pose is
    # the next sample's, and the goal repeats the last.
    g_end = np.concatenate(gears)
    c_end = np.concatenate(curvs)
    direction = np.concatenate((g_end, g_end[-1:])).astype(np.int8)
    curvature = np.concatenate((c_end, c_end[-1:]))
    return all_poses, direction, curvature


def _no_path(found: Any, settings: CarSettings, search: Any, limit: int, ok: int) -> None:
    if found.status == limit:
        raise NoPathError(
            f"no path found within {found.expanded} search states",
            hint="the goal may be unreachable for this footprint and turn radius; try a "
            "smaller --min-turn-radius or footprint, or a goal in more open space",
        )
    if not settings.reverse:
        with_reverse = search(True, min(settings.max_expanded, 500_000))
        if with_reverse.status == ok:
            raise NoPathError(
                f"no forward-only path: the goal pose cannot be reached without reversing "
                f"({found.expanded} states explored)",
                hint="pass --reverse to allow gear changes, or give a goal heading the robot "
                "can reach driving forwards",
            )
    raise NoPathError(
        f"no path: every pose reachable from the start was explored ({found.expanded} "
        "states) without reaching the goal pose",
        hint="the footprint does not fit through the way to the goal; try a smaller "
        "--footprint or --min-turn-radius, or another goal",
    )
