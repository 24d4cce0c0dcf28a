"""Pictures and videos of the hand and its skin, for checking a policy by eye and for docs.

* `skin_map_image`: the skin "unrolled" onto a plane, one square per taxel, coloured
  by its reading. The placement is derived from the `SkinLayout` alone, so any skin
  can be drawn.
* `frame_with_skin` / `SkinPanel`: a camera frame with the skin map beside it.
* `render_episode`: run a policy in a `BaodingEnv` and write an MP4 or GIF of one env.
* `save_skin_picture`: the skin map beside a 3D scatter of the taxels, as a PNG.
* `launch_viewer`: the interactive MuJoCo viewer (needs a display).

Offscreen rendering needs an OpenGL backend chosen before `mujoco` is first
imported: on a machine without a display set ``MUJOCO_GL=egl`` (or ``osmesa``).
Importing this module first does that for you when no display is set.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

if "mujoco" not in sys.modules and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
    # mujoco picks its GL backend at import; the default (GLFW) needs a display.
    os.environ.setdefault("MUJOCO_GL", "egl")

import imageio.v2 as imageio
import matplotlib
import mujoco
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import PolyCollection
from matplotlib.colors import ListedColormap, Normalize
from matplotlib.figure import Figure

from tacgnn.hand.skin_layout import Patch, SkinLayout

if TYPE_CHECKING:
    from mpl_toolkits.mplot3d import Axes3D

Policy = Callable[[Any], np.ndarray]

DEFAULT_VMAX = 0.5
"""Reading (N) shown with the top colour; a Baoding ball presses single taxels up to ~0.45 N."""
IDLE_COLOUR = (0.3, 0.3, 0.3, 1.0)
# plasma without its darkest quarter, so that a weak reading never looks like an idle taxel
SKIN_CMAP = ListedColormap(matplotlib.colormaps["plasma"](np.linspace(0.25, 1.0, 256)),
                           name="skin").with_extremes(under=IDLE_COLOUR)

_GAP = 2.0  # cells between patches (room for a label)
_DISTAL_RANK = {"distal": 0, "tip": 0, "medial": 1, "middle": 1, "proximal": 2, "base": 3}


class RenderingUnavailable(RuntimeError):
    """No OpenGL context could be created for offscreen rendering."""


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


# --- rendering the simulation -------------------------------------------------------------

def _renderer(model: mujoco.MjModel, height: int, width: int) -> mujoco.Renderer:
    if width > model.vis.global_.offwidth or height > model.vis.global_.offheight:
        raise ValueError(f"{width}x{height} exceeds the scene's offscreen buffer "
                         f"({model.vis.global_.offwidth}x{model.vis.global_.offheight})")
    try:
        return mujoco.Renderer(model, height, width)
    except Exception as err:  # GL errors come as several types, depending on the backend
        raise RenderingUnavailable(
            f"cannot create an OpenGL context (MUJOCO_GL={os.environ.get('MUJOCO_GL', '')!r}): {err}. "
            "Without a display, set MUJOCO_GL=egl (or osmesa) before mujoco is imported.") from err


class _EnvCamera:
    """Renders one env of a batch: copies its state into an MjData and draws it."""

    def __init__(self, env, env_index: int, width: int, height: int, camera: str = "overview"):
        batch = env.sim.batch
        self.batch, self.index, self.camera = batch, env_index, camera
        self.model = batch.get_model(env_index)
        self.data = mujoco.MjData(self.model)
        self.renderer = _renderer(self.model, height, width)

    def sync(self) -> mujoco.MjData:
        self.batch.get_data(self.index, self.data)
        mujoco.mj_forward(self.model, self.data)
        return self.data

    def render(self) -> np.ndarray:
        self.renderer.update_scene(self.sync(), camera=self.camera)
        return self.renderer.render()

    def close(self) -> None:
        self.renderer.close()


class _VideoWriter:
    """MP4 (H.264) or GIF by the path's suffix, frames appended one at a time."""

    def __init__(self, path: Path, fps: float):
        suffix = path.suffix.lower()
        if suffix == ".gif":
            self._writer = imageio.get_writer(path, duration=1000.0 / fps, loop=0)
        elif suffix in (".mp4", ".m4v", ".mov"):
            self._writer = imageio.get_writer(path, fps=fps, codec="libx264", quality=7,
                                              pixelformat="yuv420p", macro_block_size=2)
        else:
            raise ValueError(f"unknown video format '{suffix}': use .mp4 or .gif")

    def append(self, frame: np.ndarray) -> None:
        h, w = frame.shape[:2]  # H.264 in yuv420p needs even sizes
        if h % 2 or w % 2:
            frame = np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
        self._writer.append_data(frame)

    def close(self) -> None:
        self._writer.close()


def _observe(env) -> Any:
    """The observation of the env's current state, for a policy's first step."""
    ids = np.arange(env.num_envs)
    return env._observe(ids, *env._skin(ids))


def _skin_readings(env, info: dict, env_index: int) -> np.ndarray:
    if "tactile" in info:
        return env.skin_to_host(info["tactile"][env_index:env_index + 1])[0]
    return env.tactile_readings(noisy=False)[env_index]


def render_episode(env, policy: Policy, path: str | os.PathLike, steps: int, env_index: int = 0,
                   width: int = 320, height: int = 240, skin: bool = True, *, obs: Any = None,
                   fps: float | None = None, camera: str = "overview") -> dict[str, Any]:
    """Step `env` `steps` times with `policy` and film env `env_index` into `path`.

    `env` is a reset `BaodingEnv`; `policy(obs)` returns the (N, 16) actions of all envs.
    Pass the `obs` of that reset, else it is taken from the env's current state. One
    frame per control step, played at real time (`fps` = 1 / control_dt) unless `fps`
    is given. Envs reset on their own when an episode ends; so does the filmed one.
    Returns counts for a log line: frames, seconds (of video), render_fps,
    mean_active_taxels, final_angle_deg, episodes_ended, return.
    """
    if steps < 1:
        raise ValueError(f"steps must be >= 1, got {steps}")
    if not 0 <= env_index < env.num_envs:
        raise ValueError(f"env_index {env_index} is outside 0..{env.num_envs - 1}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fps = fps or 1.0 / env.control_dt
    writer = _VideoWriter(path, fps)  # fails early on a bad suffix
    cam = _EnvCamera(env, env_index, width, height, camera)
    panel = SkinPanel(env.tactile.layout, height) if skin else None
    obs = _observe(env) if obs is None else obs
    active, angle, ended, ret = [], 0.0, 0, 0.0
    start = time.perf_counter()
    try:
        for step in range(steps):
            obs, reward, terminated, truncated, info = env.step(np.asarray(policy(obs)))
            ret += float(reward[env_index])
            ended += bool(terminated[env_index] or truncated[env_index])
            angle = float(info["angle_deg"][env_index])
            readings = _skin_readings(env, info, env_index)
            active.append(int(np.count_nonzero(readings)))
            frame = cam.render()
            if panel is not None:
                caption = f"step {step + 1}   {angle:+.0f} deg   {active[-1]} taxels"
                frame = frame_with_skin(frame, env.tactile.layout, readings, caption, panel)
            writer.append(frame)
    finally:
        writer.close()
        cam.close()
    wall = time.perf_counter() - start
    return {"path": str(path), "frames": steps, "seconds": steps / fps, "render_fps": steps / wall,
            "mean_active_taxels": float(np.mean(active)), "final_angle_deg": angle,
            "episodes_ended": ended, "return": ret}


def save_skin_picture(env, path: str | os.PathLike, env_index: int = 0, vmax: float = DEFAULT_VMAX) -> Path:
    """PNG of env `env_index`'s skin now: the 2D skin map beside the taxels in 3D.

    Readings are noise-free (documentation, not data); balls are drawn as wireframes
    when the env has them.
    """
    layout = env.tactile.layout
    readings = env.tactile_readings(noisy=False)[env_index]
    pos = env.taxel_positions()[env_index]
    width, height = skin_map(layout).size
    fig = _new_figure(11, 5.5, dpi=120)
    ax2d = fig.add_axes((0.02, 0.05, 0.40, 0.88))
    skin_map_image(layout, readings, ax=ax2d, vmax=vmax)
    ax2d.set_title(f"skin map: {np.count_nonzero(readings)} of {layout.num_taxels} taxels active", fontsize=9)

    ax3d = cast("Axes3D", fig.add_axes((0.47, 0.02, 0.52, 0.94), projection="3d"))
    on = readings > 0
    idle, pressed = pos[~on], pos[on]
    ax3d.scatter(idle[:, 0], idle[:, 1], idle[:, 2], s=3, color=IDLE_COLOUR, depthshade=False)
    ax3d.scatter(pressed[:, 0], pressed[:, 1], pressed[:, 2], s=14, c=readings[on], cmap=SKIN_CMAP,
                 norm=Normalize(1e-9, vmax), depthshade=False)
    if hasattr(env, "ball_positions"):
        radius = env.config.ball_radius
        u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 16), np.linspace(0, np.pi, 9))
        sphere = radius * np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)])
        for centre, colour in zip(env.ball_positions()[env_index], ("tab:red", "tab:blue")):
            ax3d.plot_wireframe(*(sphere + centre[:, None, None]), color=colour, linewidth=0.4, alpha=0.5)
    lo, hi = pos.min(0), pos.max(0)
    ax3d.set_box_aspect(hi - lo)
    ax3d.view_init(elev=40, azim=-90)  # from the wrist side, like the "overview" camera
    ax3d.set_xlabel("x (m)", fontsize=7)
    ax3d.set_ylabel("y (m)", fontsize=7)
    ax3d.set_zlabel("z (m)", fontsize=7)
    ax3d.tick_params(labelsize=6)
    ax3d.set_title("taxels in the world frame", fontsize=9)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    return path


# --- interactive ----------------------------------------------------------------------------

def _draw_taxels(scene: mujoco.MjvScene, positions: np.ndarray, readings: np.ndarray, vmax: float) -> None:
    """Mark the activated taxels in a viewer scene as small spheres coloured by reading."""
    on = np.flatnonzero(readings > 0)[: scene.maxgeom]
    colours = SKIN_CMAP(np.clip(readings[on] / vmax, 0.0, 1.0)).astype(np.float32)
    eye = np.eye(3).ravel()
    for k, i in enumerate(on):
        mujoco.mjv_initGeom(scene.geoms[k], mujoco.mjtGeom.mjGEOM_SPHERE, np.array([0.0015, 0, 0]),
                            positions[i].astype(np.float64), eye, colours[k])
    scene.ngeom = len(on)


def launch_viewer(env, policy: Policy, *, obs: Any = None, show_taxels: bool = True,
                  vmax: float = DEFAULT_VMAX) -> None:
    """Run `policy` in `env` at real time and show env 0 in MuJoCo's interactive viewer.

    Stops when the window is closed. Activated taxels show as coloured dots. Needs a
    display; on a headless machine use `render_episode` (the `tacgnn render` command).
    """
    no_display = "no display; use `tacgnn render` to write a video instead"
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise RuntimeError(f"the interactive viewer needs a window, but there is {no_display}")
    import glfw  # the viewer's window library; comes with mujoco
    import mujoco.viewer

    # The viewer starts GLFW in a thread where a failure cannot be caught: try it here first.
    if not glfw.init():
        raise RuntimeError(f"cannot open a window (GLFW failed to start): {no_display}")
    model = env.sim.batch.get_model(0)
    data = env.sim.batch.get_data(0)
    mujoco.mj_forward(model, data)
    try:
        viewer = mujoco.viewer.launch_passive(model, data)
    except Exception as err:
        raise RuntimeError(f"cannot open the interactive viewer ({err}): {no_display}") from err
    obs = _observe(env) if obs is None else obs
    with viewer:
        while viewer.is_running():
            start = time.perf_counter()
            obs, _, _, _, info = env.step(np.asarray(policy(obs)))
            with viewer.lock():
                env.sim.batch.get_data(0, data)
                mujoco.mj_forward(model, data)
                if show_taxels:
                    _draw_taxels(viewer.user_scn, env.taxel_positions()[0], _skin_readings(env, info, 0), vmax)
            viewer.sync()
            time.sleep(max(0.0, env.control_dt - (time.perf_counter() - start)))
