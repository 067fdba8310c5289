"""The OpenCV plot canvas behind plan.png: tick steps and labels, where things land in the
picture, the map layer under the origin's yaw and when reduced, the PNG it writes, and the
car-like plan's picture.

References are independent of the canvas: a brute-force list of 1-2-5 steps, the cells' world
centres from :func:`slamcli.formats.occupancy.cell_to_world`, and the PNG read back by
``cv2.imread``.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
import pytest
from numpy.typing import NDArray

from slamcli.errors import ExportError
from slamcli.formats.occupancy import cell_to_world
from slamcli.planning.canvas import (
    BLUE,
    GREEN,
    MARGIN_PX,
    RED,
    Canvas,
    nice_step,
    tick_label,
    ticks,
)
from slamcli.planning.costmap import map_bounds
from slamcli.types import OccupancyGrid


def _px(canvas: Canvas, xy: tuple[float, float]) -> tuple[int, int]:
    col, row = np.rint(canvas.to_pixel(xy)).astype(int)
    return int(col), int(row)


def _palette_colours(
    labels: NDArray[np.int64], palette: NDArray[np.uint8]
) -> Callable[[slice, slice], NDArray[np.uint8]]:
    def colours(rows: slice, cols: slice) -> NDArray[np.uint8]:
        return palette[labels[rows, cols]]

    return colours


# --- ticks ------------------------------------------------------------------------------------

NICE = sorted(m * 10.0**k for k in range(-6, 8) for m in (1, 2, 5))


def test_nice_step_is_the_smallest_1_2_5_step_that_fits() -> None:
    rng = np.random.default_rng(4)
    for _ in range(500):
        span = float(10.0 ** rng.uniform(-3, 5))
        n = int(rng.integers(1, 15))
        want = min(s for s in NICE if span / s <= n * (1 + 1e-9))
        assert nice_step(span, n) == pytest.approx(want, rel=1e-12), (span, n)
    # Exact fits take the step itself: 10 m in 5 ticks is a 2 m step, not 5.
    assert nice_step(10.0, 5) == pytest.approx(2.0)
    assert nice_step(87.0, 10) == pytest.approx(10.0)


def test_ticks_cover_the_range_with_readable_labels() -> None:
    rng = np.random.default_rng(5)
    for _ in range(300):
        lo = float(rng.uniform(-500, 500)) * float(10.0 ** rng.integers(-3, 2))
        hi = lo + float(10.0 ** rng.uniform(-2, 3))
        n = int(rng.integers(2, 12))
        values, labels = ticks(lo, hi, n)
        assert len(values) >= 2
        step = values[1] - values[0]
        # The 1-2-5 step that fits, or the coarsest finer one that leaves two ticks.
        fits = nice_step(hi - lo, n)
        two = [
            t
            for t in NICE
            if t <= fits * (1 + 1e-9) and math.floor(hi / t + 1e-9) > math.ceil(lo / t - 1e-9)
        ]
        assert step == pytest.approx(max(two), rel=1e-9)
        assert values[0] >= lo - 1e-9 * step and values[-1] <= hi + 1e-9 * step
        # Every multiple of the step inside the range, none outside.
        assert values[0] - step < lo and values[-1] + step > hi
        np.testing.assert_allclose(np.diff(values), step, rtol=1e-9)
        np.testing.assert_allclose(values / step, np.rint(values / step), atol=1e-6)
        for v, text in zip(values, labels, strict=True):
            assert float(text) == pytest.approx(v, abs=step * 1e-6)
            assert not re.fullmatch(r"-0(\.0*)?", text)
            # As many decimals as the step needs, no more (zero is just "0").
            decimals = len(text.split(".")[1]) if "." in text else 0
            want = max(0, -math.floor(math.log10(step) + 1e-9))
            assert decimals == (0 if text == "0" else want), (text, step)
    assert tick_label(-1e-12, 0.5) == "0"
    assert tick_label(-2.5, 0.5) == "-2.5"
    assert ticks(-61.0, 26.0, 10)[1] == ["-60", "-50", "-40", "-30", "-20", "-10", "0", "10", "20"]


def test_tick_marks_are_drawn_at_their_values() -> None:
    canvas = Canvas((-3.3, 17.1, -2.2, 6.4))
    image = canvas.render()
    ph, pw = canvas.plot.shape[:2]
    xmin, xmax, ymin, ymax = canvas.view
    xt, _ = ticks(xmin, xmax, pw // 70)
    yt, _ = ticks(ymin, ymax, ph // 45)
    assert len(xt) >= 4 and len(yt) >= 3
    below = canvas.top + ph + 2  # a row crossing the x tick marks
    cols = [_px(canvas, (float(x), ymin))[0] for x in xt]
    assert (image[below, cols] < 128).all()
    gaps = np.setdiff1d(np.arange(canvas.left, canvas.left + pw), cols)
    assert (image[below, gaps] == 255).all()
    left = canvas.left - 3  # a column crossing the y tick marks
    rows = [_px(canvas, (xmin, float(y)))[1] for y in yt]
    assert (image[rows, left] < 128).all()
    gaps = np.setdiff1d(np.arange(canvas.top, canvas.top + ph), rows)
    assert (image[gaps, left] == 255).all()


# --- layout -----------------------------------------------------------------------------------


def test_equal_aspect_y_up_and_the_view_centred() -> None:
    view = (2.0, 12.0, -1.0, 4.0)
    canvas = Canvas(view)
    k = canvas.scale_px_per_m
    p = canvas.to_pixel([[5.0, 1.0], [6.0, 1.0], [5.0, 2.0]])
    np.testing.assert_allclose(p[1] - p[0], [k, 0.0])
    np.testing.assert_allclose(p[2] - p[0], [0.0, -k])  # y up: row decreases
    # The asked view fits the plot area exactly across, and its corners land on its edges.
    ph, pw = canvas.plot.shape[:2]
    assert k == pytest.approx(pw / 10.0)
    np.testing.assert_allclose(
        canvas.to_pixel((2.0, canvas.view[3])), [canvas.left - 0.5, canvas.top - 0.5]
    )
    assert ph == round(5.0 * k)


@pytest.mark.parametrize(("view", "short_axis"), [((0, 100, 0, 1), "y"), ((0, 1, 0, 100), "x")])
def test_extreme_aspects_widen_the_short_side(view: tuple[float, ...], short_axis: str) -> None:
    canvas = Canvas(view, min_plot_px=150, max_plot_px=900)  # type: ignore[arg-type]
    ph, pw = canvas.plot.shape[:2]
    assert 150 <= ph <= 900
    xmin, xmax, ymin, ymax = canvas.view
    # Equal aspect, the asked view inside and centred.
    assert (xmax - xmin) / pw == pytest.approx((ymax - ymin) / ph)
    assert xmin <= view[0] + 1e-9 and xmax >= view[1] - 1e-9
    assert ymin <= view[2] + 1e-9 and ymax >= view[3] - 1e-9
    assert (xmin + xmax) / 2 == pytest.approx((view[0] + view[1]) / 2)
    assert (ymin + ymax) / 2 == pytest.approx((view[2] + view[3]) / 2)
    widened = (xmax - xmin) - (view[1] - view[0]) if short_axis == "x" else (ymax - ymin) - 1
    assert widened > 0


def test_long_tick_labels_widen_the_margins() -> None:
    short = Canvas((0.0, 40.0, 0.0, 20.0))
    utm = Canvas((330000.0, 330040.0, 4500000.0, 4500020.0))
    assert short.left == MARGIN_PX["left"] and utm.left > short.left
    assert utm.plot.shape[1] == 800 - utm.left - utm.right
    assert utm.right > short.right == MARGIN_PX["right"]
    image = utm.render()
    _, _, yt, yl = utm._ticks()
    assert yl[0].startswith("450")
    # Each y tick label's ink lies between the turned axis label's strip and the plot area.
    for y in yt:
        row = _px(utm, (utm.view[0], float(y)))[1]
        # (left of the tick marks, which take the 5 columns before the plot area,
        # and right of the axis label, written in columns 8 to about 20).
        ink = np.flatnonzero(image[row - 3 : row + 4, 21 : utm.left - 5].min(axis=(0, 2)) < 128)
        assert len(ink) and ink.min() + 21 >= 28 and ink.max() + 21 <= utm.left - 8


def test_an_empty_view_is_refused() -> None:
    with pytest.raises(ExportError, match=r"x 1 \.\. 1 m") as info:
        Canvas((1.0, 1.0, 0.0, 2.0))
    assert info.value.hint
    with pytest.raises(ExportError, match="nan"):
        Canvas((0.0, 1.0, math.nan, 2.0))


def test_legend_rows_flow_below_the_plot() -> None:
    one = Canvas((0, 10, 0, 5))
    many = Canvas((0, 10, 0, 5))
    for k in range(12):
        many.legend(f"entry number {k}", "line", BLUE)
    one.legend("entry number 0", "line", BLUE)
    one.legend("entry number 0", "marker", RED)  # the same label again: one entry
    h1, h12 = one.render().shape[0], many.render().shape[0]
    assert h12 > h1 and (h12 - h1) % 22 == 0
    # Legend rows hold ink, and the swatch of the one entry is its colour.
    image = one.render()
    legend = image[MARGIN_PX["top"] + one.plot.shape[0] + MARGIN_PX["bottom"] :]
    assert (np.abs(legend.astype(int) - BLUE).sum(axis=2) < 60).any()
    assert not (np.abs(legend.astype(int) - RED).sum(axis=2) < 60).any()


# --- drawing ----------------------------------------------------------------------------------


def test_shapes_land_at_their_world_points() -> None:
    canvas = Canvas((0.0, 20.0, 0.0, 10.0))
    canvas.polyline([[1.0, 1.0], [19.0, 1.0]], BLUE, width=3)
    canvas.polyline([[1.0, 3.0], [19.0, 3.0]], RED, width=3, style="dashed")
    canvas.markers([[4.0, 6.0], [8.0, 6.0]], "o", GREEN, size_px=10)
    canvas.markers((12.0, 6.0), "*", RED, size_px=16)
    canvas.markers((16.0, 6.0), "x", BLUE, size_px=12)
    canvas.circle((4.0, 8.5), 0.8, RED, alpha=0.5)
    canvas.circle((8.0, 8.5), 0.8, BLUE, fill=False, width=2)
    canvas.arrow((11.0, 8.5), (15.0, 8.5), GREEN, width=2)
    image = canvas.render()

    def at(xy: tuple[float, float]) -> NDArray[np.int64]:
        col, row = _px(canvas, xy)
        return image[row, col].astype(np.int64)

    assert (at((10.0, 1.0)) == BLUE).all()
    for xy in ((4.0, 6.0), (8.0, 6.0)):
        assert (at(xy) == GREEN).all()
    assert (at((12.0, 6.0)) == RED).all()
    assert (at((16.0, 6.0)) == BLUE).all()  # the cross's centre
    half = np.rint(0.5 * np.array(RED) + 0.5 * 255)
    assert (np.abs(at((4.0, 8.5)) - half) <= 1).all()
    assert (at((8.0, 8.5)) == 255).all() and (at((8.8, 8.5)) == BLUE).all()
    assert (at((13.0, 8.5)) == GREEN).all()
    # The dashed line: 7 px on and 4 px off, so about 7/11 of its run is drawn.
    row = _px(canvas, (0.0, 3.0))[1]
    c0, c1 = _px(canvas, (2.0, 3.0))[0], _px(canvas, (18.0, 3.0))[0]
    drawn = (np.abs(image[row, c0:c1].astype(int) - RED).sum(axis=1) < 60).mean()
    assert 7 / 11 - 0.1 < drawn < 7 / 11 + 0.1
    # Nothing drawn where nothing was asked.
    assert (at((10.0, 4.5)) == 255).all()


def test_text_is_written_centred_and_outlined() -> None:
    canvas = Canvas((0.0, 10.0, 0.0, 5.0), background=(0, 0, 0))
    canvas.text((5.0, 2.5), "12-40 s")
    plot = canvas.plot
    col, row = np.rint(canvas._plot_px((5.0, 2.5))).astype(int)
    ink = np.argwhere(plot.sum(axis=2) > 0)
    # Ink (the white outline and the black text on it) around the point, and nowhere else.
    assert abs(ink[:, 1].mean() - col) < 3 and abs(ink[:, 0].mean() - row) < 3
    assert np.ptp(ink[:, 1]) < 80 and np.ptp(ink[:, 0]) < 20
    assert (plot == 255).all(axis=2).any()


# --- the map layer ----------------------------------------------------------------------------


@pytest.mark.parametrize("yaw", [0.0, math.pi / 2, 3.14, 0.6])
def test_map_cells_land_at_their_world_centres(yaw: float) -> None:
    rng = np.random.default_rng(8)
    h, w = 9, 14
    palette = rng.integers(90, 256, (16, 3)).astype(np.uint8)
    palette[0] = (0, 0, 0)  # the occupied cell
    labels = rng.integers(1, 16, (h, w))
    labels[6, 11] = 0
    grid = OccupancyGrid(np.zeros((h, w), np.float32), 0.25, (1.5, -2.0, yaw))
    xmin, xmax, ymin, ymax = map_bounds(grid)
    background = (40, 200, 90)
    canvas = Canvas((xmin - 1, xmax + 1, ymin - 1, ymax + 1), background=background)
    canvas.draw_map(grid, _palette_colours(labels, palette))
    image = canvas.render()
    rc = np.argwhere(np.ones((h, w), dtype=bool))
    centres = cell_to_world(grid, rc)
    px = np.rint(canvas.to_pixel(centres)).astype(int)
    np.testing.assert_array_equal(image[px[:, 1], px[:, 0]], palette[labels[rc[:, 0], rc[:, 1]]])
    col, row = _px(canvas, tuple(cell_to_world(grid, (6, 11))))
    assert (image[row, col] == 0).all()
    # Outside the map the plot keeps its background.
    outside = [(xmin - 0.5, ymin - 0.5), (xmax + 0.5, ymax + 0.5), (xmin - 0.5, ymax + 0.5)]
    for xy in outside:
        col, row = _px(canvas, xy)
        assert (image[row, col] == background).all()


def test_a_thin_wall_stays_dark_when_cells_are_smaller_than_pixels() -> None:
    h, w = 1500, 2400  # 120 x 75 m at 5 cm: about 3.4 cells per pixel across
    labels = np.zeros((h, w), dtype=np.int64)
    labels[700, 100:2300] = 1  # one cell thick, along x
    labels[100:1400, 1203] = 1  # one cell thick, along y
    palette = np.array([[255, 255, 255], [0, 0, 0]], dtype=np.uint8)
    grid = OccupancyGrid(np.zeros((h, w), np.float32), 0.05, (-10.0, 5.0, 0.0))
    xmin, xmax, ymin, ymax = map_bounds(grid)
    canvas = Canvas((xmin, xmax, ymin, ymax), background=(0, 0, 255))
    assert 1.0 / (canvas.scale_px_per_m * 0.05) > 3
    canvas.draw_map(grid, _palette_colours(labels, palette))
    image = canvas.render()
    grey = image.astype(int).sum(axis=2)
    # Along the walls (their ends left aside), within a pixel of their line, pure black.
    along_x = cell_to_world(grid, np.column_stack((np.full(400, 700), np.linspace(130, 2270, 400))))
    for col, row in np.rint(canvas.to_pixel(along_x)).astype(int):
        assert grey[row - 1 : row + 2, col].min() == 0
    along_y = cell_to_world(
        grid, np.column_stack((np.linspace(130, 1370, 300), np.full(300, 1203)))
    )
    for col, row in np.rint(canvas.to_pixel(along_y)).astype(int):
        assert grey[row, col - 1 : col + 2].min() == 0
    # Away from the walls, free cells keep their exact white.
    free = cell_to_world(grid, [[300, 300], [1100, 2000], [300, 2000], [1100, 600]])
    for col, row in np.rint(canvas.to_pixel(free)).astype(int):
        assert (image[row - 2 : row + 3, col - 2 : col + 3] == 255).all()
    # A wall pixel is about one pixel thick, not smeared: the rows beside it are white.
    col, row = _px(canvas, tuple(cell_to_world(grid, (700, 600))))
    assert (grey[row - 3 : row + 4, col] == 0).sum() <= 2


# --- the file ---------------------------------------------------------------------------------


def _scene() -> Canvas:
    grid = OccupancyGrid(np.zeros((30, 40), np.float32), 0.1, (0.0, 0.0, 0.3))
    labels = (np.arange(30)[:, None] + np.arange(40)[None, :]) % 3
    palette = np.array([[255, 255, 255], [0, 0, 0], [200, 200, 200]], dtype=np.uint8)
    canvas = Canvas((-1.5, 4.5, -0.5, 4.5), "a title: 1.23 m")
    canvas.draw_map(grid, _palette_colours(labels, palette))
    canvas.grid_lines()
    canvas.polyline([[0.0, 0.0], [2.0, 3.0], [4.0, 1.0]], BLUE, style="dotted", label="path")
    canvas.markers((2.0, 3.0), "*", RED, size_px=14, label="goal")
    canvas.text((1.0, 1.0), "3+ s")
    return canvas


def test_png_reads_back_as_the_picture_and_is_deterministic(tmp_path: Path) -> None:
    canvas = _scene()
    path = canvas.save(tmp_path / "a.png")
    back = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert back is not None
    np.testing.assert_array_equal(back[..., ::-1], canvas.render())
    assert back.shape[1] == 800
    _scene().save(tmp_path / "b.png")
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()


def test_an_unwritable_path_is_an_export_error(tmp_path: Path) -> None:
    with pytest.raises(ExportError, match="cannot write the plot") as info:
        _scene().save(tmp_path / "missing" / "plan.png")
    assert info.value.hint


# --- the car-like plan's picture --------------------------------------------------------------


def test_car_plan_picture_colours_the_gears(tmp_path: Path) -> None:
    from planning_data import BAY_GOAL, YARD_CAR, YARD_RADIUS_M, YARD_START, yard

    from slamcli.planning.car import CarSettings, plan_car
    from slamcli.planning.car_motion import CarLimits
    from slamcli.planning.car_plot import BLOCKED_GREY, car_plan_canvas, plot_car_plan

    limits = CarLimits(max_speed=2.0, wheelbase_m=2.7, min_turn_radius_m=YARD_RADIUS_M)
    result = plan_car(yard(), YARD_START, BAY_GOAL, CarSettings(YARD_CAR, YARD_RADIUS_M), limits)
    assert result.reversals >= 1
    canvas = car_plan_canvas(result)
    path = plot_car_plan(tmp_path / "plan.png", result)
    image = cv2.imread(str(path))[..., ::-1].astype(int)
    np.testing.assert_array_equal(image, canvas.render())

    def near(xy: NDArray[np.float64], colour: tuple[int, int, int]) -> bool:
        col, row = np.rint(canvas.to_pixel(xy)).astype(int)
        patch = image[row - 1 : row + 2, col - 1 : col + 2]
        return bool((np.abs(patch - colour).sum(axis=2) < 40).any())

    # Poses of one gear at least 2 m from any pose of the other gear, the start and the goal
    # (where the lines, markers and arrows overlap).
    xy = result.poses[:-1, :2]
    gear = result.direction[:-1]
    ends = np.array([result.start[:2], result.goal[:2]])

    def apart(mine: NDArray[np.bool_]) -> NDArray[np.int64]:
        others = np.vstack((xy[~mine], ends))
        d = np.hypot(*(xy[:, None, :] - others[None, :, :]).transpose(2, 0, 1)).min(axis=1)
        return np.flatnonzero(mine & (d > 2.0))

    fwd, rev = apart(gear > 0), apart(gear < 0)
    assert len(fwd) > 100 and len(rev) > 0
    for i in fwd[:: len(fwd) // 10]:
        assert near(xy[i], BLUE), i
    for i in rev:
        assert near(xy[i], RED), i
    # A blocked cell deep inside a wall shows the blocked grey (a grid line may cross the
    # patch: the median ignores it).
    blocked = result.blocked
    inner = blocked.copy()
    for dr in (-3, 0, 3):
        for dc in (-3, 0, 3):
            inner &= np.roll(blocked, (dr, dc), axis=(0, 1))
    view = canvas.view
    walls = cell_to_world(result.grid, np.argwhere(inner))
    inside = (walls[:, 0] > view[0] + 1) & (walls[:, 0] < view[1] - 1)
    inside &= (walls[:, 1] > view[2] + 1) & (walls[:, 1] < view[3] - 1)
    col, row = np.rint(canvas.to_pixel(walls[inside][len(walls[inside]) // 2])).astype(int)
    assert np.median(image[row - 2 : row + 3, col - 2 : col + 3, 0]) == BLOCKED_GREY
    # The legend names both gears even though the picture is mostly forward.
    assert canvas.legend_labels[:3] == ["footprint", "forward", "reverse"]


def test_report_grid_keeps_one_cell_walls_when_shrunk() -> None:
    """The matplotlib drawing the run reports use reduces cells the same way: a wall one cell
    wide stays black in every row when four cells share a pixel."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from slamcli.planning.plot import draw_grid, occupancy_colours

    prob = np.zeros((200, 200), dtype=np.float32)
    prob[:, 101] = 1.0
    grid = OccupancyGrid(prob, 0.05, (0.0, 0.0, 0.0))
    fig = Figure()
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    drawn = draw_grid(
        ax, grid, lambda r, c: occupancy_colours(grid.prob, r, c), (0.0, 10.0, 0.0, 10.0), 50
    )
    image = np.asarray(drawn.get_array())
    assert image.shape[1] == 50
    grey = image[..., :3].min(axis=2)
    assert (grey[:, 101 // 4] == 0).all()
    assert (np.delete(grey, 101 // 4, axis=1) == 255).all()
