"""Real-skin pipeline: baseline, clip, threshold, gain; calibration files; dead taxels."""

import numpy as np
import pytest

from tacgnn.cli import main as cli_main
from tacgnn.hand.skin_layout import default_skin
from tacgnn.real.skin import (
    CalibrationError,
    SkinCalibration,
    SkinProcessor,
    calibrate,
    load_raw_frames,
    patch_gain_from_load,
)

LAYOUT = default_skin()
T = LAYOUT.num_taxels
OFFSETS = LAYOUT.offsets()
NAMES = [p.name for p in LAYOUT.patches]


def rest_frames(n=200, seed=0, dead=(5, 300)):
    rng = np.random.default_rng(seed)
    baseline = rng.uniform(100, 200, T)
    frames = baseline + rng.normal(0, 2.0, (n, T))
    frames[:, list(dead)] = 0.0
    return frames


def split(raw):
    return {name: raw[OFFSETS[i]:OFFSETS[i + 1]] for i, name in enumerate(NAMES)}


def test_pipeline_matches_the_authors_steps():
    frames = rest_frames()
    calib = calibrate(frames, sigmas=4.0, gain=0.01)
    proc = SkinProcessor(calib)
    assert not proc(split(frames[0])).any()  # noise at rest reads 0
    press = frames[1].copy()
    press[[10, 11, 400]] += [50.0, 5.0, 100.0]  # 5 is within the noise threshold (~8)
    out = proc(split(press))
    assert out.dtype == np.float32 and out.shape == (T,)
    assert set(np.flatnonzero(out)) == {10, 400}
    expected = np.maximum(press - calib.baseline, 0.0) * 0.01
    np.testing.assert_allclose(out[[10, 400]], expected[[10, 400]], rtol=1e-6)


def test_dead_taxels_are_found_and_read_zero():
    frames = rest_frames(dead=(5, 300))
    calib = calibrate(frames)
    proc = SkinProcessor(calib)
    assert np.flatnonzero(calib.dead).tolist() == [5, 300]
    assert proc.describe(np.array([5, 300])) == ["palm[5]", "middle_tip[43]"]
    spike = frames[0].copy()
    spike[5] = 1e4
    assert proc(split(spike))[5] == 0.0
    # a session where every live taxel is pressed but one
    session = frames[:3].copy()
    session[0] += 100.0
    session[0, 42] = calib.baseline[42]
    assert proc.never_active(session).tolist() == [42]


def test_wiring_order_maps_driver_taxels_to_simulator_order():
    frames = rest_frames(dead=())
    order = np.random.default_rng(1).permutation(T)
    calib = calibrate(frames, order=order)
    proc = SkinProcessor(calib)
    raw = frames[0].copy()
    raw[order[7]] += 80.0  # the driver's taxel that is our taxel 7
    assert np.flatnonzero(proc.process_raw(raw)).tolist() == [7]


def test_gain_from_a_known_load_makes_the_patch_sum_to_the_force():
    frames = rest_frames(dead=())
    calib = calibrate(frames)
    loaded = frames[:20].copy()
    i = NAMES.index("index_tip")
    loaded[:, OFFSETS[i] + 30:OFFSETS[i] + 34] += 40.0
    calib = patch_gain_from_load(calib, loaded, "index_tip", force_newtons=0.5)
    readings = SkinProcessor(calib).process_raw(loaded)
    np.testing.assert_allclose(readings[:, OFFSETS[i]:OFFSETS[i + 1]].sum(1).mean(), 0.5, rtol=1e-5)


def test_calibration_file_round_trip_and_validation(tmp_path):
    calib = calibrate(rest_frames())
    back = SkinCalibration.load(calib.save(tmp_path / "c.npz"))
    for name in ("baseline", "threshold", "gain", "dead", "order"):
        np.testing.assert_array_equal(getattr(back, name), getattr(calib, name))
    assert back.patch_names == tuple(NAMES)
    np.savez(tmp_path / "bad.npz", baseline=calib.baseline)
    with pytest.raises(CalibrationError, match=r"bad.npz: missing array\(s\) \['threshold'"):
        SkinCalibration.load(tmp_path / "bad.npz")
    arrays = dict(np.load(tmp_path / "c.npz"))
    arrays["gain"] = arrays["gain"].copy()
    arrays["gain"][3] = np.nan
    np.savez(tmp_path / "nan.npz", **arrays)
    with pytest.raises(CalibrationError, match=r"nan.npz: 'gain' has non-finite values at taxels \[3\]"):
        SkinCalibration.load(tmp_path / "nan.npz")
    arrays["gain"][3] = 1.0
    arrays["threshold"] = arrays["threshold"][:-1]
    np.savez(tmp_path / "short.npz", **arrays)
    with pytest.raises(CalibrationError, match=r"'threshold' must have shape \(653,\)"):
        SkinCalibration.load(tmp_path / "short.npz")


def test_bad_frames_are_rejected_naming_the_patch():
    proc = SkinProcessor(calibrate(rest_frames()))
    frame = split(rest_frames()[0])
    frame["thumb_tip"] = frame["thumb_tip"][:-1]
    with pytest.raises(ValueError, match="patch 'thumb_tip' has 71 values, expected 72"):
        proc(frame)
    frame = split(rest_frames()[0])
    frame["palm"][0] = np.nan
    with pytest.raises(ValueError, match="patch 'palm' holds non-finite"):
        proc(frame)
    with pytest.raises(ValueError, match="missing patches \\['ring_tip'\\]"):
        proc({k: v for k, v in split(rest_frames()[0]).items() if k != "ring_tip"})
    with pytest.raises(CalibrationError, match="rest frames hold non-finite"):
        calibrate(np.full((3, T), np.nan))


def test_cli_calibrates_from_per_patch_files(tmp_path, capsys):
    frames = rest_frames(dead=(2,))
    np.savez(tmp_path / "rest.npz", **{n: frames[:, OFFSETS[i]:OFFSETS[i + 1]] for i, n in enumerate(NAMES)})
    assert load_raw_frames(tmp_path / "rest.npz").shape == (200, T)
    out = tmp_path / "calib.npz"
    assert cli_main(["calibrate-skin", str(tmp_path / "rest.npz"), "--out", str(out)]) == 0
    assert "1 dead taxels (always 0): palm[2]" in capsys.readouterr().out
    assert SkinCalibration.load(out).dead.sum() == 1
    np.savez(tmp_path / "partial.npz", palm=frames[:, :113])
    assert cli_main(["calibrate-skin", str(tmp_path / "partial.npz"), "--out", str(out)]) == 2
    assert "missing patch array(s)" in capsys.readouterr().err
