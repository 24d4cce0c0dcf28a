"""Videos and skin pictures: files come out right, and the skin map draws any layout."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")  # before mujoco is imported: offscreen GL without a display

import imageio.v3 as iio  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from tacgnn.envs.baoding import BaodingConfig, BaodingEnv  # noqa: E402
from tacgnn.hand.skin_layout import SkinLayout, default_skin  # noqa: E402
from tacgnn.tools.render import (  # noqa: E402
    RenderingUnavailable,
    SkinPanel,
    figure_to_array,
    frame_with_skin,
    render_episode,
    save_skin_picture,
    skin_map,
    skin_map_image,
)


@pytest.fixture(scope="module")
def env():
    env = BaodingEnv(BaodingConfig(num_envs=2))
    env.reset(seed=0)
    return env


def hold_pose(env):
    """A constant policy: every env keeps env 0's initial joint targets."""
    action = np.tile(env.last_action[:1], (2, 1))
    return lambda obs: action


def rendered(call):
    try:
        return call()
    except RenderingUnavailable as err:
        pytest.skip(f"no OpenGL context: {err}")


def test_gif_has_one_frame_per_step(env, tmp_path):
    path = tmp_path / "episode.gif"
    summary = rendered(lambda: render_episode(env, hold_pose(env), path, steps=5))
    assert path.exists() and path.stat().st_size > 0
    frames = iio.imread(path)
    assert frames.shape[0] == 5 == summary["frames"]
    assert frames.shape[1] == 240 and frames.shape[2] > 320  # camera plus skin panel
    assert all(frame.reshape(-1, frame.shape[-1]).std(0).max() > 5 for frame in frames)  # not one colour
    assert summary["seconds"] == pytest.approx(5 * env.control_dt)
    assert summary["mean_active_taxels"] > 0  # the balls rest on the palm


def test_unknown_video_suffix_is_refused(env, tmp_path):
    with pytest.raises(ValueError, match="mp4 or .gif"):
        render_episode(env, hold_pose(env), tmp_path / "episode.avi", steps=1)


def test_skin_picture_is_written(env, tmp_path):
    path = save_skin_picture(env, tmp_path / "skin.png")
    assert iio.imread(path).shape[0] > 100


def pressed(layout: SkinLayout) -> np.ndarray:
    readings = np.zeros(layout.num_taxels)
    readings[[0, 5, layout.num_taxels - 1]] = (0.1, 0.3, 0.5)
    return readings


def fewer_patches() -> SkinLayout:
    keep = ("palm", "index_tip", "index_medial", "thumb_tip")
    return SkinLayout(patches=tuple(p for p in default_skin().patches if p.name in keep))


def fingertips_only() -> SkinLayout:
    return SkinLayout(patches=tuple(p for p in default_skin().patches if p.name.endswith("_tip")))


@pytest.mark.parametrize("layout", [default_skin(), default_skin().with_pitch_scale(0.8), fewer_patches(),
                                    fingertips_only()], ids=["default", "pitch1.5", "fewer", "tips"])
def test_skin_map_shows_activations(layout):
    blank = figure_to_array(skin_map_image(layout, np.zeros(layout.num_taxels)))
    touched = figure_to_array(skin_map_image(layout, pressed(layout)))
    assert blank.shape == touched.shape
    assert np.any(blank != touched)


@pytest.mark.parametrize("layout", [default_skin(), fewer_patches(), fingertips_only()],
                         ids=["default", "fewer", "tips"])
def test_every_taxel_has_its_own_cell(layout):
    smap = skin_map(layout)
    assert smap.cells.shape == (layout.num_taxels, 2)
    assert len({tuple(c) for c in smap.cells}) == layout.num_taxels
    assert (smap.cells >= 0).all() and (smap.cells + 1 <= np.array(smap.size) + 1e-9).all()


def test_frame_with_skin_keeps_the_camera_image():
    layout = default_skin()
    rgb = np.full((120, 160, 3), 200, np.uint8)
    frame = frame_with_skin(rgb, layout, pressed(layout), panel=SkinPanel(layout, 120))
    assert frame.dtype == np.uint8 and frame.shape[0] == 120 and frame.shape[1] > 160
    assert np.array_equal(frame[:, :160], rgb)
    with pytest.raises(ValueError, match="653 readings"):
        frame_with_skin(rgb, layout, np.zeros(10))
