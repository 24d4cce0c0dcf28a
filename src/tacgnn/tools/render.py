"""Pictures and videos of the hand and its skin, for checking a policy by eye and for docs.

* `skin_map_image`, `frame_with_skin` / `SkinPanel` (`tacgnn.tools.skin_map`): the skin
  "unrolled" onto a plane, one square per taxel, coloured by its reading.
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
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

if "mujoco" not in sys.modules and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
    # mujoco picks its GL backend at import; the default (GLFW) needs a display.
    os.environ.setdefault("MUJOCO_GL", "egl")

import imageio.v2 as imageio
import mujoco
import numpy as np
from matplotlib.colors import Normalize

from tacgnn.tools.skin_map import (  # noqa: F401 - the skin map's names, also reachable from here
    DEFAULT_VMAX,
    IDLE_COLOUR,
    SKIN_CMAP,
    SkinMap,
    SkinPanel,
    _new_figure,
    figure_to_array,
    frame_with_skin,
    skin_map,
    skin_map_image,
)

if TYPE_CHECKING:
    from mpl_toolkits.mplot3d import Axes3D

Policy = Callable[[Any], np.ndarray]


class RenderingUnavailable(RuntimeError):
    """No OpenGL context could be created for offscreen rendering."""


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
    mean_active_taxels, final_angle_deg, episodes_ended, return; and `busiest`, the step
    with the most taxels touched (readings, taxel_pos, ball_pos, step) for `save_skin_picture`.
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
    busiest: dict[str, Any] = {}
    start = time.perf_counter()
    try:
        for step in range(steps):
            obs, reward, terminated, truncated, info = env.step(np.asarray(policy(obs)))
            ret += float(reward[env_index])
            ended += bool(terminated[env_index] or truncated[env_index])
            angle = float(info["angle_deg"][env_index])
            readings = _skin_readings(env, info, env_index)
            active.append(int(np.count_nonzero(readings)))
            if active[-1] >= max(active):  # the busiest moment, for a skin picture
                busiest = {"readings": readings.copy(), "taxel_pos": env.taxel_positions()[env_index].copy(),
                           "ball_pos": info["ball_pos"][env_index].copy(), "step": step + 1}
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
            "episodes_ended": ended, "return": ret, "busiest": busiest}


def save_skin_picture(env, path: str | os.PathLike, env_index: int = 0, vmax: float = DEFAULT_VMAX,
                      moment: dict[str, Any] | None = None) -> Path:
    """PNG of env `env_index`'s skin: the 2D skin map beside the taxels in 3D.

    Shows `moment` (readings, taxel_pos and ball_pos of one step, e.g. `render_episode`'s
    'busiest') when given, else the skin now; right after a reset the balls are still
    dropping and nothing touches it. Readings are noise-free (documentation, not data);
    balls are drawn as wireframes when the env has them.
    """
    layout = env.tactile.layout
    if moment:
        readings, pos, balls = moment["readings"], moment["taxel_pos"], moment["ball_pos"]
    else:
        readings = env.tactile_readings(noisy=False)[env_index]
        pos = env.taxel_positions()[env_index]
        balls = env.ball_positions()[env_index] if hasattr(env, "ball_positions") else None
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
    if balls is not None:
        radius = env.config.ball_radius
        u, v = np.meshgrid(np.linspace(0, 2 * np.pi, 16), np.linspace(0, np.pi, 9))
        sphere = radius * np.stack([np.cos(u) * np.sin(v), np.sin(u) * np.sin(v), np.cos(v)])
        for centre, colour in zip(balls, ("tab:red", "tab:blue")):
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
