"""The skin drawn flat: each taxel a square on a map laid out like a hand seen from the palm.

* `skin_map`: where each taxel goes, derived from the `SkinLayout` alone, so any skin can be drawn.
* `skin_map_image`: the map coloured by the readings, as a figure.
* `SkinPanel` / `frame_with_skin`: the map beside a camera frame, fast enough for videos.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import cast

import matplotlib
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import PolyCollection
from matplotlib.colors import ListedColormap, Normalize
from matplotlib.figure import Figure

from tacgnn.hand.skin_layout import Patch, SkinLayout

DEFAULT_VMAX = 0.5
"""Reading (N) shown with the top colour; a Baoding ball presses single taxels up to ~0.45 N."""
IDLE_COLOUR = (0.3, 0.3, 0.3, 1.0)
# plasma without its darkest quarter, so that a weak reading never looks like an idle taxel
SKIN_CMAP = ListedColormap(matplotlib.colormaps["plasma"](np.linspace(0.25, 1.0, 256)),
                           name="skin").with_extremes(under=IDLE_COLOUR)

_GAP = 2.0  # cells between patches (room for a label)
_DISTAL_RANK = {"distal": 0, "tip": 0, "medial": 1, "middle": 1, "proximal": 2, "base": 3}


# --- where each taxel goes on the 2D map --------------------------------------------------

@dataclass(frozen=True)
class SkinMap:
    """2D placement of a skin's taxels, in units of one cell, y up.

    cells: (T, 2) lower-left corner of each taxel's square, in skin vector order.
    boxes: per patch (name, x0, y0, width, height) of its grid.
    labels: (text, x, y) of each label: the bottom centre of its text.
    size: (width, height) of the whole map, labels included.
    """

    cells: np.ndarray
    boxes: tuple[tuple[str, float, float, float, float], ...]
    labels: tuple[tuple[str, float, float], ...]
    size: tuple[float, float]


def _patch_grid(patch: Patch) -> tuple[np.ndarray, int, int]:
    """(size, 2) cell of each taxel inside the patch's box, and the box's width and height.

    The patch is seen from outside its surface with its link's +z (towards the fingertip)
    up, so what touches the right of a link lights the right of its picture.
    """
    normal = np.asarray(patch.normal, float)
    right = np.cross([0.0, 0.0, 1.0], normal)
    if np.linalg.norm(right) < 1e-6:  # a pad facing along the link: any fixed choice will do
        right = np.array([0.0, 1.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(normal, right)
    if patch.surface == "capsule":  # rows climb the profile, columns go around the axis
        row_dir, col_dir = np.array([0.0, 0.0, 1.0]), right
    else:
        row_dir = np.asarray(patch.row_axis, float)
        col_dir = np.cross(normal, row_dir)
    rows, cols = patch.grid_cells().T
    if abs(row_dir @ up) >= abs(row_dir @ right):  # rows stack vertically
        x = cols if col_dir @ right >= 0 else patch.cols - 1 - cols
        y = rows if row_dir @ up >= 0 else patch.rows - 1 - rows
        return np.stack([x, y], 1), patch.cols, patch.rows
    x = rows if row_dir @ right >= 0 else patch.rows - 1 - rows
    y = cols if col_dir @ up >= 0 else patch.cols - 1 - cols
    return np.stack([x, y], 1), patch.rows, patch.cols


def _group(patch: Patch) -> str:
    return "palm" if "palm" in (patch.name, patch.body) else patch.name.split("_")[0]


def _distal_rank(patch: Patch) -> int:
    for name in (patch.body, patch.name):
        rank = _DISTAL_RANK.get(name.split("_")[-1])
        if rank is not None:
            return rank
    return len(_DISTAL_RANK)


@lru_cache(maxsize=16)
def skin_map(layout: SkinLayout) -> SkinMap:
    """Lay the patches out like a hand seen from the palm side, fingers up.

    Palm patches sit side by side at the bottom; every other group of patches (by
    the name before the first "_", e.g. "index") is a column, tip on top. The
    fingers stand above the palm, the first one listed nearest the thumb; the
    "thumb" column stands to the right, as the "overview" camera shows the hand.
    """
    patches = layout.patches
    grids = [_patch_grid(p) for p in patches]
    groups: dict[str, list[int]] = {}
    for i, p in enumerate(patches):
        groups.setdefault(_group(p), []).append(i)
    origin = np.zeros((len(patches), 2))  # lower-left corner of each patch's box

    def column(ids: list[int]) -> float:
        """Stack patches `ids` tip on top, corners relative to the column; return its width."""
        ids = sorted(ids, key=lambda i: _distal_rank(patches[i]))
        width = max(grids[i][1] for i in ids)
        y = 0.0
        for i in reversed(ids):
            origin[i] = ((width - grids[i][1]) / 2, y)
            y += grids[i][2] + _GAP
        return width

    def shift(ids: list[int], dx: float, dy: float) -> None:
        origin[ids] += (dx, dy)

    palm = groups.pop("palm", [])
    thumb = groups.pop("thumb", [])
    palm_w = palm_h = 0.0
    for i in palm:
        origin[i] = (palm_w, 0.0)
        palm_w += grids[i][1] + _GAP
        palm_h = max(palm_h, grids[i][2])
    palm_w = max(palm_w - _GAP, 0.0)
    # fingers: right to left, starting next to the thumb
    finger_y = palm_h + 1.5 * _GAP if palm else 0.0
    widths = [column(ids) for ids in groups.values()]
    fingers_w = sum(widths) + _GAP * (len(widths) - 1) if widths else 0.0
    fingers_right = (palm_w + fingers_w) / 2 if palm else fingers_w  # centred over the palm
    right = fingers_right
    for ids, w in zip(groups.values(), widths):
        shift(ids, right - w, finger_y)
        right -= w + _GAP
    if thumb:
        column(thumb)
        shift(thumb, max(palm_w, fingers_right) + _GAP, 0.0)

    origin -= origin.min(0)
    cells = np.concatenate([origin[i] + g[0] for i, g in enumerate(grids)]).astype(float)
    cells.flags.writeable = False  # shared by the cache
    boxes = tuple((p.name, float(origin[i][0]), float(origin[i][1]), g[1], g[2])
                  for i, (p, g) in enumerate(zip(patches, grids)))
    # Short labels fit a narrow column: "tip" over each patch, "index" over its column.
    labels = []
    for group, ids in [("palm", palm), ("thumb", thumb), *groups.items()]:
        for i in ids:
            name, x0, y0, w, h = boxes[i]
            short = name[len(group) + 1:] if len(ids) > 1 and name.startswith(group + "_") else name
            labels.append((short.replace("_", " "), x0 + w / 2, y0 + h + 0.3))
        if len(ids) > 1 and group != "palm":
            top = max(boxes[i][2] + boxes[i][4] for i in ids)
            centre = np.mean([boxes[i][1] + boxes[i][3] / 2 for i in ids])
            labels.append((group.upper(), float(centre), top + _GAP + 0.3))
    extent = np.max([(b[1] + b[3], b[2] + b[4]) for b in boxes], axis=0)
    top = max(extent[1] + _GAP, max(y for _, _, y in labels) + _GAP)
    return SkinMap(cells=cells, boxes=boxes, labels=tuple(labels), size=(float(extent[0]), float(top)))


def _draw_skin(ax, layout: SkinLayout, readings: np.ndarray, vmax: float, text_colour: str,
               fontsize: float) -> PolyCollection:
    """Draw the skin map into `ax`; return the cells, whose colours follow `set_array`."""
    smap = skin_map(layout)
    square = np.array([(0.06, 0.06), (0.94, 0.06), (0.94, 0.94), (0.06, 0.94)])
    cells = PolyCollection(smap.cells[:, None, :] + square, cmap=SKIN_CMAP,
                           norm=Normalize(vmin=1e-9, vmax=vmax), edgecolors="none")
    cells.set_array(_checked(readings, layout))
    ax.add_collection(cells)
    for text, x, y in smap.labels:
        ax.text(x, y, text, ha="center", va="bottom", fontsize=fontsize, color=text_colour)
    width, height = smap.size
    ax.set_xlim(-0.5, width + 0.5)
    ax.set_ylim(-0.5, height + 0.5)
    ax.set_aspect("equal")
    ax.set_axis_off()
    return cells


def _checked(readings: np.ndarray, layout: SkinLayout) -> np.ndarray:
    readings = np.asarray(readings, dtype=float).ravel()
    if readings.shape != (layout.num_taxels,):
        raise ValueError(f"expected {layout.num_taxels} readings for this skin, got {readings.shape[0]}")
    return readings


def _new_figure(width_in: float, height_in: float, dpi: float = 100) -> Figure:
    """A figure on its own Agg canvas: no pyplot, no GUI backend, no global state."""
    fig = Figure(figsize=(width_in, height_in), dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def figure_to_array(fig: Figure) -> np.ndarray:
    """(H, W, 3) uint8 pixels of a figure drawn on an Agg canvas."""
    canvas = cast(FigureCanvasAgg, fig.canvas)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def skin_map_image(layout: SkinLayout, readings: np.ndarray, ax=None, vmax: float = DEFAULT_VMAX):
    """The skin unrolled onto a plane (see `skin_map`), cells coloured by reading (N).

    Idle taxels are dark grey, activated ones follow a colormap up to `vmax`. Draws
    into `ax` if given, else into a new figure; returns the figure.
    """
    if ax is None:
        width, height = skin_map(layout).size
        scale, bar = 0.12, 1.0  # inches per cell, inches for the colour bar
        fig = _new_figure(width * scale + bar + 0.2, height * scale + 0.2)
        fig_w, fig_h = fig.get_size_inches()
        ax = fig.add_axes((0.1 / fig_w, 0.1 / fig_h, width * scale / fig_w, height * scale / fig_h))
        cells = _draw_skin(ax, layout, readings, vmax, "black", fontsize=6)
        cax = fig.add_axes((1 - 0.8 * bar / fig_w, 0.3, 0.15 / fig_w, 0.4))
        fig.colorbar(cells, cax=cax, extend="min", label="reading (N)")
        return fig
    cells = _draw_skin(ax, layout, readings, vmax, "black", fontsize=5)
    ax.figure.colorbar(cells, ax=ax, shrink=0.5, extend="min", label="reading (N)")
    return ax.figure


class SkinPanel:
    """A skin map of fixed pixel height kept between video frames.

    Only the cell colours and a caption change from frame to frame, so they are drawn
    over a saved background (blitting): ~2 ms a frame instead of ~30 ms for a redraw.
    """

    def __init__(self, layout: SkinLayout, height: int = 240, vmax: float = DEFAULT_VMAX, dpi: float = 100):
        self.layout = layout
        width, map_height = skin_map(layout).size
        caption_cells = 3.0
        cell_px = height / (map_height + 1 + caption_cells)
        bar_px = max(36, int(0.22 * height))
        map_px = int(np.ceil(cell_px * (width + 1)))
        self.width = map_px + bar_px
        self.height = height
        self.fig = _new_figure(self.width / dpi, height / dpi, dpi)
        self.fig.set_facecolor("#1b1b1b")
        self.canvas = cast(FigureCanvasAgg, self.fig.canvas)  # _new_figure's
        ax = self._ax = self.fig.add_axes((0, 0, map_px / self.width, 1))
        fontsize = float(np.clip(1.4 * cell_px * 72 / dpi, 3.5, 8))
        self.cells = _draw_skin(ax, layout, np.zeros(layout.num_taxels), vmax, "0.8", fontsize)
        ax.set_ylim(-0.5, map_height + 0.5 + caption_cells)
        self.caption = ax.text(0.03, 0.995, "", transform=ax.transAxes, ha="left", va="top",
                               fontsize=fontsize * 1.2, color="white")
        bar_ax = self.fig.add_axes((map_px / self.width + 0.1 * bar_px / self.width, 0.25,
                                    0.18 * bar_px / self.width, 0.5))
        bar = self.fig.colorbar(self.cells, cax=bar_ax, extend="min")
        bar.ax.tick_params(labelsize=fontsize, colors="0.8", length=2)
        bar.outline.set_edgecolor("0.5")
        bar_ax.set_title("N", fontsize=fontsize, color="0.8")
        for artist in (self.cells, self.caption):
            artist.set_animated(True)
        self.canvas.draw()
        self._background = self.canvas.copy_from_bbox(self.fig.bbox)

    def image(self, readings: np.ndarray, caption: str = "") -> np.ndarray:
        """(height, width, 3) uint8 picture of the skin with these readings."""
        canvas = self.canvas
        canvas.restore_region(self._background)
        self.cells.set_array(_checked(readings, self.layout))
        self.caption.set_text(caption)
        self._ax.draw_artist(self.cells)  # both live in the map's axes
        self._ax.draw_artist(self.caption)
        return np.asarray(canvas.buffer_rgba())[..., :3].copy()


@lru_cache(maxsize=4)
def _panel(layout: SkinLayout, height: int) -> SkinPanel:
    return SkinPanel(layout, height)


def frame_with_skin(rgb: np.ndarray, layout: SkinLayout, readings: np.ndarray,
                    caption: str = "", panel: SkinPanel | None = None) -> np.ndarray:
    """The camera image `rgb` (H, W, 3) with the skin map of the same height to its right."""
    rgb = np.asarray(rgb, dtype=np.uint8)
    panel = panel or _panel(layout, rgb.shape[0])
    skin = panel.image(readings, caption)
    if skin.shape[0] != rgb.shape[0]:  # a panel made for another height
        skin = _fit_height(skin, rgb.shape[0])
    return np.concatenate([rgb, skin], axis=1)


def _fit_height(image: np.ndarray, height: int) -> np.ndarray:
    rows = np.clip(np.round(np.linspace(0, image.shape[0] - 1, height)).astype(int), 0, image.shape[0] - 1)
    return image[rows]
