"""A small raster canvas for plots in world metres (y up), drawn with OpenCV.

The plans' pictures (plan.png) are drawn here rather than with matplotlib, whose import alone
costs a quarter of a second. A :class:`Canvas` holds a plot area at screen resolution with
equal aspect, and lays out around it a title, axis ticks at "nice" steps (1, 2 or 5 x 10^k m)
with their labels, the axis labels and a legend row below the plot. Lines, markers and
outlines are anti-aliased and placed to 1/16 pixel.

Pixel coordinates are (col, row) of the whole picture, with integers at pixel centres:
:meth:`Canvas.to_pixel` turns world points into them. Colours are RGB tuples of 0..255.

A map is drawn from the cells in view only, reduced in blocks of whole cells to about one
cell per pixel and placed with one affine warp (the origin's yaw, the scale and the y flip),
so a map of millions of cells costs little more than a small one. The reduction keeps the
darker colour: each channel of a block is its cells' minimum, so a wall one cell thick stays
dark at any scale, and a block whose cells share one colour keeps it exactly.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from slamcli.errors import ExportError
from slamcli.types import OccupancyGrid

RGB = tuple[int, int, int]

BLUE: RGB = (31, 119, 180)
ORANGE: RGB = (255, 127, 14)
GREEN: RGB = (44, 160, 44)
RED: RGB = (214, 39, 40)
PURPLE: RGB = (148, 103, 189)
BLACK: RGB = (0, 0, 0)
WHITE: RGB = (255, 255, 255)

WIDTH_PX = 800
"""Width of a canvas's picture, pixels."""

MARGIN_PX = {"left": 74, "right": 22, "top": 36, "bottom": 48}
"""Room around the plot area (px): the title above; the tick labels and axis labels left and
below (the side margins grow for long tick labels). The legend rows come below the bottom
margin."""

LEGEND_ROW_PX = 22
_SWATCH_PX = 28
"""Length of a legend entry's sample line."""
_YLABEL_PX = 30
"""Room left of the y tick labels for the turned axis label."""
FONT_SCALE = 0.45
TITLE_SCALE = 0.52
DASHES = {"dashed": (6.0, 4.0), "dotted": (1.5, 2.5)}
"""Visible on and off lengths of the broken line styles, in line widths (px for width 1)."""

_SHIFT = 4
"""Fractional bits of the coordinates handed to OpenCV's drawing functions (1/16 pixel)."""
_FONT = 0  # cv2.FONT_HERSHEY_SIMPLEX
_AA = 16  # cv2.LINE_AA
_FRAME: RGB = (70, 70, 70)
_GRID_KEEP = 0.82
"""Grid lines scale the pixels under them by this factor (white becomes light grey)."""


def cells_in_view(
    grid: OccupancyGrid, view: tuple[float, float, float, float]
) -> tuple[int, int, int, int] | None:
    """(r0, r1, c0, c1): the block of the grid's cells (rows r0..r1-1, columns c0..c1-1) that
    covers ``view`` = (xmin, xmax, ymin, ymax) world metres with the origin's yaw, plus a cell
    of margin; None when no cell is in view."""
    from slamcli.planning.costmap import world_to_uv

    h, w = np.asarray(grid.prob).shape
    xmin, xmax, ymin, ymax = view
    corners = world_to_uv(grid, [[xmin, ymin], [xmax, ymin], [xmin, ymax], [xmax, ymax]])
    c0 = max(math.floor(corners[:, 0].min()) - 1, 0)
    r0 = max(math.floor(corners[:, 1].min()) - 1, 0)
    c1 = min(math.ceil(corners[:, 0].max()) + 1, w)
    r1 = min(math.ceil(corners[:, 1].max()) + 1, h)
    if c0 >= c1 or r0 >= r1:
        return None
    return r0, r1, c0, c1


def darkest_blocks(image: NDArray[np.uint8], block: int) -> NDArray[np.uint8]:
    """An (h, w, c) uint8 image reduced in ``block`` x ``block`` squares (the last ones cut by
    the edge), each channel the square's minimum: darker wins, so a one-cell wall shrunk to a
    pixel stays as dark as it was, and a square of one colour keeps it exactly."""
    if block <= 1:
        return image
    import cv2

    kernel = np.ones((block, block), dtype=np.uint8)
    pooled = cv2.erode(np.ascontiguousarray(image), kernel, anchor=(0, 0))
    return np.ascontiguousarray(np.asarray(pooled, dtype=np.uint8)[::block, ::block])


def nice_step(span: float, max_ticks: int) -> float:
    """The smallest step of the form 1, 2 or 5 x 10^k that cuts ``span`` (> 0, metres) into at
    most ``max_ticks`` (>= 1) intervals."""
    raw = span / max(max_ticks, 1)
    power = 10.0 ** math.floor(math.log10(raw))
    for m in (1.0, 2.0, 5.0, 10.0):
        step = m * power
        if span / step <= max_ticks * (1.0 + 1e-9):
            return step
    return 10.0 * power


def tick_label(value: float, step: float) -> str:
    """``value`` with as many decimals as ``step`` needs (0 for steps of 1 and more)."""
    decimals = max(0, -math.floor(math.log10(step) + 1e-9))
    text = f"{value:.{decimals}f}"
    return "0" if float(text) == 0.0 else text


def ticks(lo: float, hi: float, max_ticks: int) -> tuple[NDArray[np.float64], list[str]]:
    """Tick values (whole multiples of :func:`nice_step` in ``[lo, hi]``) and their labels.

    When that step leaves fewer than two ticks in the range, the next finer 1-2-5 steps are
    tried until two fit, so an axis always shows a scale.
    """
    step = nice_step(hi - lo, max_ticks)
    while True:
        i0 = math.ceil(lo / step - 1e-9)
        i1 = math.floor(hi / step + 1e-9)
        if i1 > i0:
            break
        mantissa = round(step / 10.0 ** math.floor(math.log10(step) + 1e-9))
        step *= 0.4 if mantissa == 5 else 0.5  # 5 -> 2, 2 -> 1, 1 -> 0.5
    values = np.arange(i0, i1 + 1, dtype=np.float64) * step
    return values, [tick_label(float(v), step) for v in values]


@dataclass(frozen=True)
class _LegendEntry:
    label: str
    kind: str  # "line", "marker" or "patch"
    colour: RGB
    width: int = 1
    style: str = "solid"
    marker: str = "o"
    size: float = 8.0
    alpha: float = 1.0


class Canvas:
    """A picture of ``view`` = (xmin, xmax, ymin, ymax) world metres, y up, equal aspect.

    The plot area's top-left corner is at pixel (``left``, ``top``) of the picture. It is
    ``width_px`` less the margins wide (``left`` and ``right`` grow for long tick labels); its
    height follows the view's aspect, kept between ``min_plot_px`` and ``max_plot_px`` by
    widening the view's short side about its centre. Draw into it in world metres (the draw
    methods clip at its edges); the frame, ticks, labels, title and legend are added by
    :meth:`render`. ``background`` is the plot area's colour where nothing is drawn.
    """

    def __init__(
        self,
        view: tuple[float, float, float, float],
        title: str = "",
        *,
        width_px: int = WIDTH_PX,
        min_plot_px: int = 150,
        max_plot_px: int = 900,
        background: RGB = WHITE,
    ) -> None:
        xmin, xmax, ymin, ymax = (float(v) for v in view)
        if not all(map(math.isfinite, (xmin, xmax, ymin, ymax))) or xmax <= xmin or ymax <= ymin:
            raise ExportError(
                f"cannot draw a plot of the area x {xmin:g} .. {xmax:g} m, "
                f"y {ymin:g} .. {ymax:g} m",
                hint="the area must be finite and not empty: check the paths and the map origin",
            )
        self.width_px = int(width_px)
        self.top = MARGIN_PX["top"]
        self.left = MARGIN_PX["left"]
        self.right = MARGIN_PX["right"]
        self._layout((xmin, xmax, ymin, ymax), min_plot_px, max_plot_px)
        # Room for long tick labels: the y labels beside the turned axis label, and half the
        # last x label beyond the plot's right edge.
        _, xl, _, yl = self._ticks()
        left = max(MARGIN_PX["left"], _widest(yl) + 8 + _YLABEL_PX)
        right = max(MARGIN_PX["right"], _widest(xl) // 2 + 4)
        if (left, right) != (self.left, self.right):
            self.left, self.right = left, right
            self._layout((xmin, xmax, ymin, ymax), min_plot_px, max_plot_px)
        self.title = title
        self.background = background
        self.plot: NDArray[np.uint8] = np.empty(self._plot_shape, dtype=np.uint8)
        self.plot[:] = background
        self._legend: list[_LegendEntry] = []

    def _layout(
        self, view: tuple[float, float, float, float], min_plot_px: int, max_plot_px: int
    ) -> None:
        """Set the scale, the plot area's size and the view it shows exactly (see the class)."""
        xmin, xmax, ymin, ymax = view
        pw = self.width_px - self.left - self.right
        scale = pw / (xmax - xmin)
        ph = (ymax - ymin) * scale
        if ph < min_plot_px:
            ph = float(min_plot_px)
        elif ph > max_plot_px:
            ph = float(max_plot_px)
            scale = ph / (ymax - ymin)
        ph_px = max(1, round(ph))
        # The view spans the plot area exactly, about the asked view's centre.
        cx, cy = 0.5 * (xmin + xmax), 0.5 * (ymin + ymax)
        half_w, half_h = 0.5 * pw / scale, 0.5 * ph_px / scale
        self.view = (cx - half_w, cx + half_w, cy - half_h, cy + half_h)
        self.scale_px_per_m = scale
        self._plot_shape = (ph_px, pw, 3)

    # --- coordinates ---------------------------------------------------------------------------

    def to_pixel(self, xy: ArrayLike) -> NDArray[np.float64]:
        """World points (..., 2) in metres -> (..., 2) ``(col, row)`` of the rendered picture,
        pixel centres at integers (``np.rint`` gives the pixel a point falls in)."""
        offset = np.array([self.left, self.top], dtype=np.float64)
        return self._plot_px(xy) + offset

    def _plot_px(self, xy: ArrayLike) -> NDArray[np.float64]:
        """World points -> (col, row) of the plot area, pixel centres at integers."""
        p = np.asarray(xy, dtype=np.float64)
        xmin, _, _, ymax = self.view
        k = self.scale_px_per_m
        return np.stack(((p[..., 0] - xmin) * k - 0.5, (ymax - p[..., 1]) * k - 0.5), axis=-1)

    def _fixed(self, xy: ArrayLike) -> NDArray[np.int32]:
        """World points -> plot-area pixels in OpenCV's fixed point (:data:`_SHIFT` bits)."""
        return np.rint(self._plot_px(xy) * (1 << _SHIFT)).astype(np.int32)

    # --- layers --------------------------------------------------------------------------------

    def draw_map(
        self, grid: OccupancyGrid, colours: Callable[[slice, slice], NDArray[np.uint8]]
    ) -> None:
        """Paint the grid's cells where they lie in the world.

        ``colours(rows, cols)`` gives the (h, w, 3) RGB or (h, w, 4) RGBA uint8 colours of a
        block of cells (row 0 at the origin, the lowest v of
        :func:`slamcli.planning.costmap.world_to_uv`). Only the cells in view are asked for;
        they are reduced in square blocks of whole cells (each channel the block's minimum, so
        darker wins) to at least one pixel per block, then warped into place with the
        nearest-neighbour rule, so a pixel inside one block shows its colour exactly.
        """
        import cv2

        res = float(grid.resolution_m)
        x0, y0, yaw = (float(v) for v in grid.origin_xy_yaw)
        xmin, ymax = self.view[0], self.view[3]
        window = cells_in_view(grid, self.view)
        if window is None:
            return
        r0, r1, c0, c1 = window
        image = np.asarray(colours(slice(r0, r1), slice(c0, c1)), dtype=np.uint8)
        if image.shape[2] == 3:
            rgba = np.empty((*image.shape[:2], 4), dtype=np.uint8)
            rgba[..., :3] = image
            rgba[..., 3] = 255
            image = rgba
        kr = self.scale_px_per_m * res  # pixels per cell
        # Blocks at least one pixel wide, so the warp's sampling skips none of them.
        block = max(1, math.ceil(1.0 / kr - 1e-6))
        image = darkest_blocks(image, block)
        # Image pixel (j, i) is centred at cell coordinates u = c0 + block (j + 1/2),
        # v = r0 + block (i + 1/2); the world point there goes to plot pixel (col, row).
        c, s = math.cos(yaw), math.sin(yaw)
        k = self.scale_px_per_m
        uc, vc = c0 + 0.5 * block, r0 + 0.5 * block
        m = np.array(
            [
                [kr * c * block, -kr * s * block, k * (x0 - xmin) - 0.5 + kr * (c * uc - s * vc)],
                [-kr * s * block, -kr * c * block, k * (ymax - y0) - 0.5 - kr * (s * uc + c * vc)],
            ]
        )
        ph, pw = self.plot.shape[:2]
        warped = cv2.warpAffine(
            image,
            m,
            (pw, ph),
            flags=cv2.INTER_NEAREST,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=(0, 0, 0, 0),
        )
        alpha = warped[..., 3]
        if not ((alpha == 0) | (alpha == 255)).all():
            a = alpha[..., None].astype(np.float32) / 255.0
            mixed = self.plot * (1.0 - a) + warped[..., :3] * a
            self.plot[:] = np.rint(mixed).astype(np.uint8)
        else:
            np.copyto(self.plot, warped[..., :3], where=(alpha == 255)[..., None])

    def grid_lines(self) -> None:
        """Light lines at the ticks across the plot area (draw after the map, before the
        paths)."""
        xt, _, yt, _ = self._ticks()
        ph, pw = self.plot.shape[:2]
        cols = np.rint(self._plot_px(np.column_stack((xt, np.zeros_like(xt))))[:, 0]).astype(int)
        rows = np.rint(self._plot_px(np.column_stack((np.zeros_like(yt), yt)))[:, 1]).astype(int)
        cols = cols[(cols >= 0) & (cols < pw)]
        rows = rows[(rows >= 0) & (rows < ph)]
        self.plot[:, cols] = (self.plot[:, cols] * _GRID_KEEP).astype(np.uint8)
        self.plot[rows, :] = (self.plot[rows, :] * _GRID_KEEP).astype(np.uint8)

    def polyline(
        self,
        xy: ArrayLike,
        colour: RGB,
        *,
        width: int = 1,
        style: str = "solid",
        closed: bool = False,
        label: str | None = None,
    ) -> None:
        """A line through the points (N, 2) metres; ``style`` solid, dashed or dotted;
        ``width`` in pixels."""
        self.polylines(
            [np.asarray(xy, dtype=np.float64)], colour, width=width, style=style, closed=closed
        )
        if label:
            self._add_legend(_LegendEntry(label, "line", colour, width=width, style=style))

    def polylines(
        self,
        lines: Sequence[ArrayLike],
        colour: RGB,
        *,
        width: int = 1,
        style: str = "solid",
        closed: bool = False,
        label: str | None = None,
    ) -> None:
        """Several lines (each (N, 2) metres) of one look, in one pass; ``closed`` joins each
        line's last point to its first (outlines of polygons)."""
        import cv2

        px = []
        for line in lines:
            pts = self._plot_px(np.asarray(line, dtype=np.float64).reshape(-1, 2))
            if closed and len(pts) > 1:
                pts = np.vstack((pts, pts[:1]))
            if len(pts):
                px.append(pts)
        if style != "solid":
            on, off = _dash_pattern(style, width)
            px = [d for pts in px for d in _dashes(pts, on, off)]
        fixed = [np.rint(p * (1 << _SHIFT)).astype(np.int32) for p in px if len(p)]
        if fixed:
            cv2.polylines(self.plot, fixed, False, colour, int(width), _AA, _SHIFT)
        if label:
            self._add_legend(_LegendEntry(label, "line", colour, width=width, style=style))

    def markers(
        self,
        xy: ArrayLike,
        kind: str,
        colour: RGB,
        *,
        size_px: float = 8.0,
        label: str | None = None,
    ) -> None:
        """Markers at the points (N, 2) or one point (2,) metres: ``kind`` "o" (disc), "*"
        (star) or "x" (cross); ``size_px`` their diameter."""
        pts = self._plot_px(np.asarray(xy, dtype=np.float64).reshape(-1, 2))
        for col, row in pts:
            _marker(self.plot, (col, row), kind, colour, size_px)
        if label:
            self._add_legend(_LegendEntry(label, "marker", colour, marker=kind, size=size_px))

    def circle(
        self,
        xy: tuple[float, float],
        radius_m: float,
        colour: RGB,
        *,
        alpha: float = 1.0,
        fill: bool = True,
        width: int = 1,
        style: str = "solid",
        label: str | None = None,
    ) -> None:
        """A circle of ``radius_m`` about ``xy`` (metres): a disc blended with ``alpha`` when
        ``fill``, else an outline of ``width`` px in ``style``."""
        import cv2

        r_px = radius_m * self.scale_px_per_m
        if fill:
            centre = self._plot_px(xy)
            ph, pw = self.plot.shape[:2]
            x0, x1 = (
                max(math.floor(centre[0] - r_px) - 1, 0),
                min(math.ceil(centre[0] + r_px) + 2, pw),
            )
            y0, y1 = (
                max(math.floor(centre[1] - r_px) - 1, 0),
                min(math.ceil(centre[1] + r_px) + 2, ph),
            )
            if x0 < x1 and y0 < y1:
                roi = self.plot[y0:y1, x0:x1]
                layer = roi.copy()
                fixed = np.rint((centre - [x0, y0]) * (1 << _SHIFT)).astype(int)
                radius = round(r_px * (1 << _SHIFT))
                cv2.circle(layer, (int(fixed[0]), int(fixed[1])), radius, colour, -1, _AA, _SHIFT)
                roi[:] = cv2.addWeighted(layer, alpha, roi, 1.0 - alpha, 0.0)
            if label:
                self._add_legend(_LegendEntry(label, "patch", colour, alpha=alpha))
            return
        n = max(24, math.ceil(2.0 * math.pi * r_px / 2.0))
        t = np.linspace(0.0, 2.0 * math.pi, n + 1)
        ring = np.column_stack((xy[0] + radius_m * np.cos(t), xy[1] + radius_m * np.sin(t)))
        self.polyline(ring, colour, width=width, style=style, label=label)

    def arrow(
        self,
        tail: tuple[float, float],
        head: tuple[float, float],
        colour: RGB,
        *,
        width: int = 2,
        head_px: float = 10.0,
    ) -> None:
        """An arrow from ``tail`` to ``head`` (metres) with a head ``head_px`` pixels long."""
        import cv2

        a, b = self._fixed(tail), self._fixed(head)
        length = float(np.hypot(*(b - a))) / (1 << _SHIFT)
        tip = min(0.5, head_px / max(length, 1e-9))
        cv2.arrowedLine(
            self.plot,
            (int(a[0]), int(a[1])),
            (int(b[0]), int(b[1])),
            colour,
            width,
            _AA,
            _SHIFT,
            tip,
        )

    def text(
        self,
        xy: tuple[float, float],
        text: str,
        colour: RGB = BLACK,
        *,
        scale: float = 0.4,
        align: str = "center",
        offset_px: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        """``text`` at ``xy`` (metres) moved by ``offset_px`` (right, down): centred on that
        point, or starting ("left") or ending ("right") there, vertically centred; outlined
        in white so it reads over lines and dark cells."""
        col, row = self._plot_px(xy) + np.asarray(offset_px, dtype=np.float64)
        _put_text(self.plot, text, (col, row), scale, colour, align, "center", halo=True)

    def legend(
        self,
        label: str,
        kind: str,
        colour: RGB,
        *,
        width: int = 1,
        style: str = "solid",
        marker: str = "o",
        size_px: float = 8.0,
        alpha: float = 1.0,
    ) -> None:
        """A legend entry without drawing anything: ``kind`` "line" (``width``, ``style``),
        "marker" (``marker``, ``size_px``) or "patch" (a square of ``colour`` at ``alpha``)."""
        self._add_legend(_LegendEntry(label, kind, colour, width, style, marker, size_px, alpha))

    @property
    def legend_labels(self) -> list[str]:
        """The legend's labels, in order."""
        return [e.label for e in self._legend]

    def _add_legend(self, entry: _LegendEntry) -> None:
        if all(e.label != entry.label for e in self._legend):
            self._legend.append(entry)

    # --- the picture ---------------------------------------------------------------------------

    def _ticks(self) -> tuple[NDArray[np.float64], list[str], NDArray[np.float64], list[str]]:
        """x tick values and labels, then y's: about one every 70 px across, 45 px up."""
        ph, pw = self._plot_shape[:2]
        xmin, xmax, ymin, ymax = self.view
        xt, xl = ticks(xmin, xmax, max(2, pw // 70))
        yt, yl = ticks(ymin, ymax, max(2, ph // 45))
        return xt, xl, yt, yl

    def _legend_rows(self) -> list[list[tuple[_LegendEntry, int]]]:
        """The legend entries flowed into rows no wider than the picture, with each entry's
        width (px)."""
        rows: list[list[tuple[_LegendEntry, int]]] = [[]]
        used = 0
        room = self.width_px - 20
        for entry in self._legend:
            w = _SWATCH_PX + 6 + _text_size(entry.label, FONT_SCALE)[0] + 22
            if rows[-1] and used + w > room:
                rows.append([])
                used = 0
            rows[-1].append((entry, w))
            used += w
        return [r for r in rows if r]

    def render(self) -> NDArray[np.uint8]:
        """The whole picture, (H, W, 3) uint8 RGB."""
        import cv2

        ph, pw = self.plot.shape[:2]
        left, top = self.left, self.top
        legend = self._legend_rows()
        height = top + ph + MARGIN_PX["bottom"] + LEGEND_ROW_PX * len(legend) + (8 if legend else 0)
        out = np.full((height, self.width_px, 3), 255, dtype=np.uint8)
        out[top : top + ph, left : left + pw] = self.plot
        cv2.rectangle(out, (left - 1, top - 1), (left + pw, top + ph), _FRAME, 1, cv2.LINE_8)

        xmin, _, ymin, _ = self.view
        xt, xl, yt, yl = self._ticks()
        bottom = top + ph
        for value, label in zip(xt, xl, strict=True):
            col = round(float(self.to_pixel((value, ymin))[0]))
            cv2.line(out, (col, bottom), (col, bottom + 4), _FRAME, 1, cv2.LINE_8)
            _put_text(out, label, (col, bottom + 7), FONT_SCALE, BLACK, "center", "top")
        for value, label in zip(yt, yl, strict=True):
            row = round(float(self.to_pixel((xmin, value))[1]))
            cv2.line(out, (left - 5, row), (left - 1, row), _FRAME, 1, cv2.LINE_8)
            _put_text(out, label, (left - 8, row), FONT_SCALE, BLACK, "right", "center")
        _put_text(out, "x (m)", (left + pw / 2, bottom + 26), FONT_SCALE, BLACK, "center", "top")
        _put_text(out, "y (m)", (8, top + ph / 2), FONT_SCALE, BLACK, "center", "top", turned=True)
        if self.title:
            scale = TITLE_SCALE
            while scale > 0.36 and _text_size(self.title, scale)[0] > self.width_px - 10:
                scale -= 0.02
            _put_text(
                out, self.title, (self.width_px / 2, top / 2), scale, BLACK, "center", "center"
            )

        y = bottom + MARGIN_PX["bottom"] + LEGEND_ROW_PX // 2
        for row_entries in legend:
            x = (self.width_px - sum(w for _, w in row_entries)) / 2 + 11
            for entry, w in row_entries:
                _swatch(out, entry, (x, y))
                _put_text(
                    out, entry.label, (x + _SWATCH_PX + 6, y), FONT_SCALE, BLACK, "left", "center"
                )
                x += w
            y += LEGEND_ROW_PX
        return out

    def encode_png(self) -> bytes:
        """The rendered picture as PNG bytes (the same picture gives the same bytes)."""
        import cv2

        ok, data = cv2.imencode(
            ".png", np.ascontiguousarray(self.render()[..., ::-1]), [cv2.IMWRITE_PNG_COMPRESSION, 3]
        )
        if not ok:
            raise ExportError("cannot encode the plot as PNG", hint="report this as a bug")
        return bytes(data.tobytes())

    def save(self, path: str | Path) -> Path:
        """Write the picture to ``path`` as PNG (the caller's temporary file, when it renames
        into place); ExportError when it cannot be written."""
        data = self.encode_png()
        try:
            Path(path).write_bytes(data)
        except OSError as exc:
            raise ExportError(
                f"{path}: cannot write the plot ({exc.strerror})",
                hint="check that the output folder exists and is writable",
            ) from exc
        return Path(path)


def _text_size(text: str, scale: float) -> tuple[int, int, int]:
    """(width, height above the baseline, depth below it) of ``text`` in pixels."""
    import cv2

    (w, h), base = cv2.getTextSize(text, _FONT, scale, 1)
    return int(w), int(h), int(base)


def _widest(texts: Sequence[str]) -> int:
    """Width (px) of the widest of ``texts`` at :data:`FONT_SCALE`; 0 for none."""
    return max((_text_size(t, FONT_SCALE)[0] for t in texts), default=0)


def _text_mask(text: str, scale: float, pad: int) -> tuple[NDArray[np.float32], int]:
    """Coverage (0..1, float32) of ``text`` written at ``scale`` with ``pad`` pixels around it,
    and the row of its baseline in that mask."""
    import cv2

    w, h, base = _text_size(text, scale)
    mask = np.zeros((h + base + 2 * pad, w + 2 * pad), dtype=np.uint8)
    cv2.putText(mask, text, (pad, pad + h), _FONT, scale, 255, 1, _AA)
    return mask.astype(np.float32) / 255.0, pad + h


def _paint(
    img: NDArray[np.uint8], mask: NDArray[np.float32], at: tuple[int, int], colour: RGB
) -> None:
    """Blend ``colour`` into ``img`` by ``mask``'s coverage, its top-left corner at ``at`` =
    (col, row); the parts outside ``img`` are left out."""
    c0, r0 = at
    h, w = mask.shape
    ih, iw = img.shape[:2]
    a0, b0 = max(r0, 0), max(c0, 0)
    a1, b1 = min(r0 + h, ih), min(c0 + w, iw)
    if a0 >= a1 or b0 >= b1:
        return
    m = mask[a0 - r0 : a1 - r0, b0 - c0 : b1 - c0, None]
    roi = img[a0:a1, b0:b1]
    roi[:] = np.rint(roi * (1.0 - m) + np.asarray(colour, dtype=np.float32) * m).astype(np.uint8)


def _put_text(
    img: NDArray[np.uint8],
    text: str,
    at: tuple[float, float],
    scale: float,
    colour: RGB,
    align: str,
    valign: str,
    *,
    halo: bool = False,
    turned: bool = False,
) -> None:
    """Write ``text`` with its anchor at ``at`` = (col, row): ``align`` left / center / right,
    ``valign`` top / center / baseline (of the text as read). ``halo`` outlines it in white,
    so it reads over lines and dark cells; ``turned`` writes it a quarter turn
    counter-clockwise (reading upwards)."""
    import cv2

    pad = 2
    mask, baseline = _text_mask(text, scale, pad)
    w, h, _ = _text_size(text, scale)
    dx = {"left": 0.0, "center": w / 2, "right": float(w)}[align]
    dy = {"top": float(h), "center": h / 2, "baseline": 0.0}[valign]
    # The mask's corner relative to the anchor, as read: (pad + dx) left, (baseline - dy) up.
    left, up = pad + dx, baseline - dy
    if turned:
        mask = np.ascontiguousarray(np.rot90(mask))
        corner = (round(at[0] - up), round(at[1] - (mask.shape[0] - left)))
    else:
        corner = (round(at[0] - left), round(at[1] - up))
    if halo:
        ring = cv2.dilate(mask, np.ones((3, 3), dtype=np.uint8))
        _paint(img, np.asarray(ring, dtype=np.float32), corner, WHITE)
    _paint(img, mask, corner, colour)


def _dash_pattern(style: str, width: int) -> tuple[float, float]:
    """On and off lengths (px) of the centre line that draw ``style``'s :data:`DASHES` at
    ``width``: OpenCV's round caps (and a 1-px line's end pixels) lengthen each dash by about
    one width."""
    on, off = (v * max(width, 1) for v in DASHES[style])
    return max(on - width, 0.25), off + width


def _dashes(pts: NDArray[np.float64], on: float, off: float) -> list[NDArray[np.float64]]:
    """The pieces (each (M, 2) pixels) of the line through ``pts`` that a pattern of ``on``
    pixels drawn and ``off`` pixels skipped, from the first point, keeps."""
    step = np.hypot(*np.diff(pts, axis=0).T)
    keep = np.concatenate(([True], step > 0))
    pts, step = pts[keep], step[step > 0]
    if len(pts) < 2:
        return [pts]
    s = np.concatenate(([0.0], np.cumsum(step)))
    starts = np.arange(0.0, s[-1], on + off)
    ends = np.minimum(starts + on, s[-1])
    a = np.column_stack((np.interp(starts, s, pts[:, 0]), np.interp(starts, s, pts[:, 1])))
    b = np.column_stack((np.interp(ends, s, pts[:, 0]), np.interp(ends, s, pts[:, 1])))
    i0 = np.searchsorted(s, starts, side="right")
    i1 = np.searchsorted(s, ends, side="left")
    return [np.vstack((a[k], pts[i0[k] : i1[k]], b[k])) for k in range(len(starts))]


def _marker(
    img: NDArray[np.uint8], at: tuple[float, float], kind: str, colour: RGB, size_px: float
) -> None:
    """Draw one marker (see :meth:`Canvas.markers`) centred at pixel ``at``."""
    import cv2

    one = 1 << _SHIFT
    centre = np.asarray(at, dtype=np.float64)
    half = 0.5 * size_px
    if kind == "o":
        c = np.rint(centre * one).astype(int)
        cv2.circle(img, (int(c[0]), int(c[1])), round(half * one), colour, -1, _AA, _SHIFT)
    elif kind == "*":
        angle = np.pi / 2 + np.arange(10) * np.pi / 5
        radius = np.where(np.arange(10) % 2 == 0, half, 0.4 * half)
        star = centre + np.column_stack((radius * np.cos(angle), -radius * np.sin(angle)))
        cv2.fillPoly(img, [np.rint(star * one).astype(np.int32)], colour, _AA, _SHIFT)
    elif kind == "x":
        d = half * math.sqrt(0.5)
        for sx in (-1.0, 1.0):
            arm = np.array([d, sx * d])
            p = np.rint((centre - arm) * one).astype(int)
            q = np.rint((centre + arm) * one).astype(int)
            cv2.line(img, (int(p[0]), int(p[1])), (int(q[0]), int(q[1])), colour, 2, _AA, _SHIFT)
    else:
        raise ExportError(f"unknown marker {kind!r}", hint="use 'o', '*' or 'x'")


def _swatch(img: NDArray[np.uint8], entry: _LegendEntry, at: tuple[float, float]) -> None:
    """Draw a legend entry's sample, its left end at ``at`` = (col, row centre)."""
    import cv2

    x, y = at
    if entry.kind == "line":
        pts = np.array([[x, y], [x + _SWATCH_PX, y]])
        pieces = (
            [pts]
            if entry.style == "solid"
            else _dashes(pts, *_dash_pattern(entry.style, entry.width))
        )
        fixed = [np.rint(p * (1 << _SHIFT)).astype(np.int32) for p in pieces]
        cv2.polylines(img, fixed, False, entry.colour, entry.width, _AA, _SHIFT)
    elif entry.kind == "marker":
        _marker(img, (x + _SWATCH_PX / 2, y), entry.marker, entry.colour, entry.size)
    else:
        c0, r0 = round(x + 4), round(y - 6)
        roi = img[r0 : r0 + 12, c0 : c0 + _SWATCH_PX - 8]
        tint = np.array(entry.colour, dtype=np.float64)
        roi[:] = np.rint(roi * (1.0 - entry.alpha) + tint * entry.alpha).astype(np.uint8)
