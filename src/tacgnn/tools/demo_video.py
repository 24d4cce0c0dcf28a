"""The demo video: several episodes of one env at 1280x720, the hand beside its skin, each
episode's end and outcome marked, a title saying what is shown.

Software OpenGL renders the hand at ~16 frames/s at 640x480 here, so the camera is drawn at
that size and everything else (text, skin map, the episodes' timeline) is composed around it
with numpy and matplotlib, blitting the parts that change: the frame costs little more than
its camera image. Physics runs at 50 Hz and the video at 25 frames/s, one frame every second
control step, so it plays at real time.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Any, cast

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg

from tacgnn.tools.render import (
    Policy,
    _EnvCamera,
    _observe,
    _skin_readings,
    _VideoWriter,
)
from tacgnn.tools.skin_map import SkinPanel, _new_figure

WIDTH, HEIGHT = 1280, 720
CAMERA = (640, 480)  # the largest the scene's offscreen buffer takes
FPS = 25.0
TOP, LEFT, GAP = 92, 24, 24
TIMELINE_Y = 662  # top of the episodes' bar
HOLD_SECONDS = 0.8  # an episode's last frame stays this long, its outcome over it
OUTCOMES = {"success": ((46, 160, 67), "SUCCESS: the balls swapped places"),
            "fall": ((214, 39, 40), "A BALL FELL"),
            "timeout": ((150, 150, 150), "TIME OUT: not turned in time")}
BACKGROUND = "#161616"


class DemoFrame:
    """Composes one 1280x720 frame: title, camera image, skin map, status and the episodes so far."""

    def __init__(self, layout, title: str, subtitle: str):
        self.fig = _new_figure(WIDTH / 100, HEIGHT / 100)
        self.fig.set_facecolor(BACKGROUND)
        self.canvas = cast(FigureCanvasAgg, self.fig.canvas)
        self.panel = SkinPanel(layout, CAMERA[1])
        self.skin_x = LEFT + CAMERA[0] + GAP
        text: dict[str, Any] = {"transform": None, "color": "white", "va": "top"}
        heading = self.fig.text(LEFT, HEIGHT - 14, title, fontsize=19, weight="bold", **text)
        width = heading.get_window_extent(self.canvas.get_renderer()).width
        if width > WIDTH - 2 * LEFT:  # a long policy name: smaller, not cut off
            heading.set_fontsize(19 * (WIDTH - 2 * LEFT) / width)
        self.fig.text(LEFT, HEIGHT - 50, subtitle, fontsize=11.5, **{**text, "color": "0.8"})
        stats_x = self.skin_x + self.panel.width + GAP
        self.fig.text(stats_x, HEIGHT - TOP, "this episode", fontsize=12, **{**text, "color": "0.7"})
        self.stats = self.fig.text(stats_x, HEIGHT - TOP - 26, "", fontsize=14, linespacing=1.7, **text)
        self.status = self.fig.text(LEFT, HEIGHT - (TOP + CAMERA[1] + 14), "", fontsize=18, weight="bold", **text)
        self.fig.text(LEFT, HEIGHT - (TIMELINE_Y - 24), "episodes so far:", fontsize=12, **{**text, "color": "0.8"})
        self.fig.text(WIDTH - LEFT, HEIGHT - (TIMELINE_Y - 24), "green: success   red: a ball fell   grey: time out",
                      fontsize=12, ha="right", **{**text, "color": "0.8"})
        self.totals = self.fig.text(LEFT + 170, HEIGHT - (TIMELINE_Y - 24), "", fontsize=12, **text)
        for artist in (self.stats, self.status, self.totals):
            artist.set_animated(True)
        self.canvas.draw()
        self.background = self.canvas.copy_from_bbox(self.fig.bbox)

    def compose(self, camera: np.ndarray, readings: np.ndarray, stats: str, status: tuple[str, tuple] | None,
                episodes: list[tuple[float, str]], elapsed: float, total: float) -> np.ndarray:
        """The frame; `episodes` holds (end time, outcome) of the finished ones, `elapsed` of `total` s."""
        self.canvas.restore_region(self.background)
        self.stats.set_text(stats)
        text, colour = status if status else ("", (255, 255, 255))
        self.status.set_text(text)
        self.status.set_color(tuple(c / 255 for c in colour))
        self.totals.set_text(_totals(episodes))
        for artist in (self.stats, self.status, self.totals):
            self.fig.draw_artist(artist)
        frame = np.asarray(self.canvas.buffer_rgba())[..., :3].copy()
        h, w = camera.shape[:2]
        frame[TOP:TOP + h, LEFT:LEFT + w] = camera
        skin = self.panel.image(readings)
        frame[TOP:TOP + skin.shape[0], self.skin_x:self.skin_x + skin.shape[1]] = skin
        if status:
            _border(frame, TOP, LEFT, h, w, colour)
        _timeline(frame, episodes, elapsed, total)
        return frame


def _border(frame: np.ndarray, top: int, left: int, h: int, w: int, colour: tuple, t: int = 8) -> None:
    frame[top:top + t, left:left + w] = colour
    frame[top + h - t:top + h, left:left + w] = colour
    frame[top:top + h, left:left + t] = colour
    frame[top:top + h, left + w - t:left + w] = colour


def _timeline(frame: np.ndarray, episodes: list[tuple[float, str]], elapsed: float, total: float) -> None:
    """A bar over the video's time: each finished episode a block in its outcome's colour, a cursor now."""
    x0, x1, y0, y1 = LEFT, WIDTH - LEFT, TIMELINE_Y, TIMELINE_Y + 36
    frame[y0:y1, x0:x1] = (45, 45, 45)

    def x(t: float) -> int:
        return x0 + int(round((x1 - x0) * min(t / total, 1.0)))

    start = 0.0
    for end, outcome in episodes:
        frame[y0 + 3:y1 - 3, x(start) + 2:max(x(end) - 2, x(start) + 3)] = OUTCOMES[outcome][0]
        start = end
    now = x(elapsed)
    frame[y0 - 6:y1 + 6, max(now - 2, x0):now + 2] = (255, 255, 255)


def _totals(episodes: list[tuple[float, str]]) -> str:
    wins = sum(o == "success" for _, o in episodes)
    return f"{len(episodes)} ended, {wins} success{'es' if wins != 1 else ''}"


def _outcome(info: dict, index: int) -> str:
    if info["success"][index]:
        return "success"
    return "fall" if info["fall"][index] else "timeout"


def render_demo(env, policy: Policy, path: str | os.PathLike, seconds: float = 16.0, *, title: str,
                obs: Any = None, env_index: int = 0) -> dict[str, Any]:
    """Film env `env_index` of a reset `BaodingEnv` acted on by `policy` for `seconds` of video.

    Episodes follow each other as the env resets them; an episode's last frame is held for
    `HOLD_SECONDS` under its outcome. Returns seconds, width, height, frames, episodes_ended,
    successes, mean_active_taxels and wall_seconds (time to make it).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = _VideoWriter(path, FPS)  # fails early on a bad suffix
    cam = _EnvCamera(env, env_index, *CAMERA)
    layout = env.tactile.layout
    subtitle = (f"Left: the hand (camera). Right: its skin unrolled flat ({layout.num_taxels} taxels, palm at the "
                "bottom, fingers up),\neach square one taxel coloured by the force it reads; grey: no contact.")
    composer = DemoFrame(layout, title, subtitle)
    steps_per_frame = max(1, int(round(1.0 / (FPS * env.control_dt))))
    total_frames = int(round(seconds * FPS))
    obs = _observe(env) if obs is None else obs
    frames, step, active = 0, 0, []
    episodes: list[tuple[float, str]] = []
    camera, readings = cam.render(), np.zeros(layout.num_taxels)
    start = time.perf_counter()
    try:
        while frames < total_frames:
            ended = None
            for _ in range(steps_per_frame):
                obs, _, terminated, truncated, info = env.step(np.asarray(policy(obs)))
                step += 1
                if terminated[env_index] or truncated[env_index]:
                    ended = _outcome(info, env_index)
                    break
                readings = _skin_readings(env, info, env_index)
            angle = float(info["angle_deg"][env_index])
            if ended is None:
                camera = cam.render()
                active.append(int(np.count_nonzero(readings)))
            episode_seconds = int(info["episode_steps"][env_index]) * env.control_dt
            stats = (f"number {len(episodes) + 1}\ntime {episode_seconds:.1f} s\nturn {angle:+.0f} deg\n"
                     f"taxels {int(np.count_nonzero(readings))}")
            if ended is None:
                frame = composer.compose(camera, readings, stats, None, episodes, frames / FPS, seconds)
                writer.append(frame)
                frames += 1
                continue
            episodes.append((frames / FPS, ended))
            colour, text = OUTCOMES[ended]
            for _ in range(int(round(HOLD_SECONDS * FPS))):  # the last frame of the episode, its outcome over it
                if frames >= total_frames:
                    break
                frame = composer.compose(camera, readings, "episode over", (text, colour), episodes, frames / FPS,
                                         seconds)
                writer.append(frame)
                frames += 1
            readings = np.zeros(layout.num_taxels)
    finally:
        writer.close()
        cam.close()
    return {"path": str(path), "seconds": frames / FPS, "width": WIDTH, "height": HEIGHT, "frames": frames,
            "episodes_ended": len(episodes), "successes": sum(o == "success" for _, o in episodes),
            "mean_active_taxels": float(np.mean(active)) if active else 0.0,
            "wall_seconds": time.perf_counter() - start}
