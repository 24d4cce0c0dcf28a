"""Perception in the RL loop: the policy sees predicted ball positions; the model learns online."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from tacgnn.config import ConfigError, to_dict
from tacgnn.envs.baoding import BaodingConfig
from tacgnn.envs.observation import BALL_COLUMNS
from tacgnn.hand.skin_layout import default_skin
from tacgnn.learning.checkpoint import load_checkpoint
from tacgnn.learning.config import PPOConfig
from tacgnn.learning.evaluate import evaluate
from tacgnn.learning.online_perception import OnlinePerception, OnlinePerceptionConfig
from tacgnn.learning.policy import load_perception
from tacgnn.learning.train import train
from tacgnn.perception.models import PerceptionModelConfig


def test_policy_trains_with_perception_in_the_loop_and_resumes(tmp_path):
    env = BaodingConfig(obs_mode="perceived")
    ppo = PPOConfig(num_envs=8, max_iterations=4, save_interval=2)
    loop = OnlinePerceptionConfig(model=PerceptionModelConfig(name="mlp"), update_every_steps=16, epochs=2,
                                  buffer_size=256)
    train(env, ppo, tmp_path / "run", perception_cfg=loop)
    ckpt = load_checkpoint(tmp_path / "run" / "model_000004.pt")
    assert ckpt["perception"]["updates"] == 2  # every 16 steps = 2 iterations of 8 steps
    perception = load_perception(tmp_path / "run" / "model_000004.pt")
    frames = np.zeros((3, 653), np.float32), np.zeros((3, 653, 3), np.float32)
    assert perception(*frames).shape == (3, 6)
    result = evaluate(tmp_path / "run" / "model_000004.pt", "simple", episodes=4, num_envs=4)
    assert 0.0 <= result["success_rate"] <= 1.0
    # resume to 6 iterations: one more perception update
    train(env, PPOConfig(num_envs=8, max_iterations=6, save_interval=2), tmp_path / "run", resume=True,
          perception_cfg=loop)
    assert load_checkpoint(tmp_path / "run" / "model_000006.pt")["perception"]["updates"] == 3


@pytest.mark.parametrize("joint_inputs", [0, 16])
def test_online_perception_learns_from_recorded_frames(tmp_path, joint_inputs):
    """Skin only (the paper) or skin and the hand's joint angles: the model learns from what it records."""
    from tacgnn.config import to_dict
    from tacgnn.envs.baoding import BaodingEnv
    from tacgnn.envs.scripted import FingerWave
    from tacgnn.learning.online_perception import OnlinePerception

    cfg = OnlinePerceptionConfig(model=PerceptionModelConfig(name="mlp", joint_inputs=joint_inputs), epochs=20,
                                 buffer_size=2048)
    env = BaodingEnv(BaodingConfig(num_envs=32, obs_mode="perceived"))
    perception = OnlinePerception(cfg, to_dict(env.config.skin))
    calls = []
    env.perception = lambda *inputs: calls.append(len(inputs)) or perception(*inputs)
    env.perception.joint_inputs = perception.joint_inputs
    obs, _ = env.reset(seed=0)
    wave = FingerWave(env.last_action[0], 32, seed=0)
    for _ in range(64):
        obs, *_, info = env.step(wave())
        perception.record(info)
    assert set(calls) == {3 if joint_inputs else 2}  # the env hands the joint angles to a model that reads them
    if joint_inputs:  # recorded beside each frame: real angles (rad) inside the hand's joint ranges
        recorded = perception.joints[:perception.size]
        assert recorded.abs().amax() > 0.1 and recorded.amin() > -0.5 and recorded.amax() < 1.75
    metrics = perception.update()
    assert metrics["perception/rmse_cm_after"] < 0.8 * metrics["perception/rmse_cm_before"]


def test_perceived_mode_needs_a_perception_config(tmp_path):
    with pytest.raises(ConfigError, match="perceived"):
        train(BaodingConfig(obs_mode="perceived"), PPOConfig(num_envs=4, max_iterations=1), tmp_path / "r")
    with pytest.raises(ConfigError, match="perceived"):
        train(BaodingConfig(), PPOConfig(num_envs=4, max_iterations=1), tmp_path / "r2",
              perception_cfg=OnlinePerceptionConfig())


def test_export_policy_is_small_and_acts_like_the_checkpoint(tmp_path):
    from tacgnn.learning.policy import export_policy, load_policy

    train(BaodingConfig(), PPOConfig(num_envs=4, max_iterations=1), tmp_path / "gt")
    ckpt = tmp_path / "gt" / "model_000001.pt"
    slim = export_policy(ckpt, tmp_path / "policy.pt")
    assert slim.stat().st_size < ckpt.stat().st_size / 2
    obs = np.random.default_rng(0).standard_normal((5, 54)).astype(np.float32)
    assert np.array_equal(load_policy(ckpt)[0](obs), load_policy(slim)[0](obs))
    # a run can start from it: actor and critic weights are loaded, the std is reset
    run = tmp_path / "ft"
    train(BaodingConfig(), PPOConfig(num_envs=4, max_iterations=1, init_from=str(ckpt), init_noise_std=0.2), run)
    assert load_checkpoint(run / "model_000001.pt")["iteration"] == 1


def test_pretrained_perception_brings_its_architecture(tmp_path):
    """A checkpoint trained offline with non-default settings (log force, jk readout, joint angles)
    starts the loop as it was trained, whatever the loop's model config says besides the model kind."""
    from tacgnn.config import to_dict
    from tacgnn.datasets.baoding_data import BaodingDataConfig, generate
    from tacgnn.learning.online_perception import OnlinePerception
    from tacgnn.perception.checkpoint import load_model
    from tacgnn.perception.train_config import PerceptionTrainConfig
    from tacgnn.perception.training import train as train_perception

    generate(BaodingDataConfig(samples=128, shard_size=128, num_envs=16), tmp_path / "data")
    cfg = PerceptionTrainConfig.for_task("baoding", "tacgnn", epochs=1, model_kw=dict(joint_inputs=16))
    train_perception(cfg, tmp_path / "data", tmp_path / "perc", log=lambda *_: None)
    offline = load_model(tmp_path / "perc" / "checkpoint.pt")[0]
    skin = to_dict(BaodingConfig().skin)
    online = OnlinePerception(OnlinePerceptionConfig(pretrained=str(tmp_path / "perc" / "checkpoint.pt")), skin)
    assert online.cfg.model.joint_inputs == 16 and online.cfg.model.pool == cfg.model.pool
    frames = np.random.default_rng(0).random((2, 653)).astype(np.float32), np.zeros((2, 653, 3))
    joints = np.full((2, 16), 0.3)
    import torch
    expected = offline(torch.from_numpy(frames[0]), torch.zeros(2, 653, 3), torch.full((2, 16), 0.3)).detach()
    np.testing.assert_allclose(online(*frames, joints), expected.numpy() / 100.0, rtol=1e-5, atol=1e-7)
    with pytest.raises(ValueError, match="mlp"):
        OnlinePerception(OnlinePerceptionConfig(model=PerceptionModelConfig(name="mlp"),
                                                pretrained=str(tmp_path / "perc" / "checkpoint.pt")), skin)


def test_warm_up_trains_the_perception_before_ppo_moves_the_policy(tmp_path, capsys):
    """warmup_rounds: the starting policy acts and the perception learns from it first; the
    policy's observation normaliser sees none of those steps, and a resumed run does not
    warm up again."""
    env = BaodingConfig(obs_mode="perceived")
    ppo = PPOConfig(num_envs=8, max_iterations=2, save_interval=2)

    def loop(rounds):
        return OnlinePerceptionConfig(model=PerceptionModelConfig(name="mlp"), update_every_steps=16, epochs=2,
                                      buffer_size=256, warmup_rounds=rounds)

    train(env, ppo, tmp_path / "plain", perception_cfg=loop(0))
    train(env, ppo, tmp_path / "warm", perception_cfg=loop(2))
    assert capsys.readouterr().out.count("[perception warm-up] round") == 2
    plain, warm = (load_checkpoint(tmp_path / r / "model_000002.pt") for r in ("plain", "warm"))
    assert warm["perception"]["updates"] == plain["perception"]["updates"] + 2
    counts = [{k: v for k, v in c["actor_state_dict"].items() if k.endswith("count")} for c in (plain, warm)]
    assert counts[0] and counts[0] == counts[1]  # normaliser statistics over the PPO steps only
    train(env, PPOConfig(num_envs=8, max_iterations=4, save_interval=2), tmp_path / "warm", resume=True,
          perception_cfg=loop(2))
    assert "warm-up" not in capsys.readouterr().out


@pytest.mark.parametrize("fault", ["loss", "gradient"])
def test_online_update_with_a_non_finite_loss_or_gradient_leaves_the_model_as_it_was(poison_loss, fault):
    import torch

    from tacgnn.config import to_dict
    from tacgnn.envs.baoding import BaodingEnv
    from tacgnn.learning.online_perception import OnlinePerception

    env = BaodingEnv(BaodingConfig(num_envs=8, obs_mode="perceived"))
    perception = OnlinePerception(OnlinePerceptionConfig(model=PerceptionModelConfig(name="mlp"), epochs=1,
                                                         batch_size=16), to_dict(env.config.skin))
    env.perception = perception
    env.reset(seed=0)
    for _ in range(8):
        *_, info = env.step(env.last_action)
        perception.record(info)
    before = {k: v.clone() for k, v in perception.model.state_dict().items()}
    poison_loss(fault, at_call=2)  # the second batch
    with pytest.raises(FloatingPointError, match=f"non-finite {fault}.*perception update 1"):
        perception.update()
    after = perception.model.state_dict()
    changed = [k for k in before if not torch.equal(before[k], after[k])]
    assert changed  # the first batch stepped ...
    assert all(torch.isfinite(after[k]).all() for k in after)  # ... the poisoned one did not
    assert perception.updates == 0


def test_evaluate_runs_a_policy_on_another_perception(tmp_path, monkeypatch):
    """--perception: a ground-truth policy reads the ball positions a perception checkpoint
    predicts (after ball tracking), and files that cannot supply them are named."""
    import torch

    import tacgnn.learning.evaluate as evaluation
    from tacgnn.datasets.baoding_data import BaodingDataConfig, generate
    from tacgnn.learning.online_perception import OnlinePerception
    from tacgnn.perception.train_config import PerceptionTrainConfig
    from tacgnn.perception.training import train as train_perception

    train(BaodingConfig(tactile=False), PPOConfig(num_envs=4, max_iterations=1), tmp_path / "gt")
    gt_policy = tmp_path / "gt" / "model_000001.pt"
    generate(BaodingDataConfig(samples=64, shard_size=64, num_envs=16), tmp_path / "data")
    train_perception(PerceptionTrainConfig.for_task("baoding", "mlp", epochs=1), tmp_path / "data",
                     tmp_path / "perc", log=lambda *_: None)
    perc = tmp_path / "perc" / "checkpoint.pt"

    seen, predicted = [], []
    policy_from_checkpoint = evaluation.policy_from_checkpoint

    def spying_policy_from_checkpoint(data, path):
        policy = policy_from_checkpoint(data, path)
        return lambda obs: seen.append(obs[:, BALL_COLUMNS].copy()) or policy(obs)

    call = OnlinePerception.__call__
    monkeypatch.setattr(evaluation, "policy_from_checkpoint", spying_policy_from_checkpoint)
    def recording_call(self, *a):
        predicted.append(call(self, *a))
        return predicted[-1]

    monkeypatch.setattr(OnlinePerception, "__call__", recording_call)
    out = evaluation.evaluate(gt_policy, "simple", episodes=2, num_envs=2, perception_from=perc)
    assert out["episodes"] == 2 and len(seen) > 1
    # every ball position the policy read is one the perception predicted, up to which ball is which
    made = np.concatenate(predicted)
    made = np.concatenate([made, np.roll(made, 3, axis=1)])
    read = np.concatenate(seen)
    gap = np.abs(read[:, None, :] - made[None]).max(-1).min(1)  # to the nearest prediction, m
    assert gap.max() < 1e-6
    assert 0 < out["perception_rmse_cm"] < 20  # an untrained perception's error in the loop, cm
    monkeypatch.undo()
    assert evaluation.evaluate(gt_policy, "simple", episodes=1, num_envs=1)["perception_rmse_cm"] is None

    with pytest.raises(ValueError, match="trained without a perception"):
        evaluation.evaluate(gt_policy, episodes=1, num_envs=1, perception_from=gt_policy)
    payload = torch.load(perc, weights_only=True)
    payload["config"]["task"], payload["config"]["model"]["out_dim"] = "cube", 9
    torch.save(payload, tmp_path / "cube.pt")
    with pytest.raises(ValueError, match="'cube' task"):
        evaluation.evaluate(gt_policy, episodes=1, num_envs=1, perception_from=tmp_path / "cube.pt")
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    from tacgnn.files import FileProblem

    with pytest.raises(FileProblem, match="junk.pt is a text file, not a perception or policy file"):
        evaluation.evaluate(gt_policy, episodes=1, num_envs=1, perception_from=tmp_path / "junk.pt")
    with pytest.raises(FileNotFoundError):
        evaluation.evaluate(gt_policy, episodes=1, num_envs=1, perception_from=tmp_path / "missing.pt")
    train(BaodingConfig(tactile=False, obs_mode="finger_torque"), PPOConfig(num_envs=4, max_iterations=1),
          tmp_path / "torque")
    with pytest.raises(ValueError, match="finger_torque"):
        evaluation.evaluate(tmp_path / "torque" / "model_000001.pt", episodes=1, num_envs=1, perception_from=perc)


def test_anchor_frames_keep_the_in_loop_model_fitting_another_distribution(tmp_path):
    """With `anchor_dataset` every update also fits frames of another source (here: the
    scripted env's own resets), so the model places them better than one trained on the buffer alone."""
    from tacgnn.datasets.baoding_data import BaodingDataConfig, generate
    from tacgnn.envs.baoding import BaodingEnv
    from tacgnn.envs.scripted import FingerWave
    from tacgnn.perception.data import load_tactile
    from tacgnn.perception.objectives import Objective

    generate(BaodingDataConfig(samples=512, shard_size=512, num_envs=16, seed=5, settle_steps=0), tmp_path / "anchor")
    anchor = load_tactile(tmp_path / "anchor", "baoding")
    env = BaodingEnv(BaodingConfig(num_envs=32, obs_mode="perceived"))
    base = OnlinePerceptionConfig(model=PerceptionModelConfig(name="mlp"), epochs=8, buffer_size=1024)
    mixed = replace(base, anchor_dataset=str(tmp_path / "anchor"), anchor_share=0.5)
    plain_model, mixed_model = (OnlinePerception(c, to_dict(env.config.skin)) for c in (base, mixed))
    env.perception = plain_model
    env.reset(seed=0)
    wave = FingerWave(env.last_action[0], 32, seed=0)
    for step in range(32):
        *_, info = env.step(wave())
        if step >= 8:  # the wave's late frames: a narrower distribution than the anchor's
            plain_model.record(info)
            mixed_model.record(info)
    for model in (plain_model, mixed_model):
        model.update()

    def anchor_rmse(model):
        with torch.no_grad():
            pred = model.model(anchor.readings.float(), anchor.positions.float())
        return Objective("baoding", True).metrics(pred, anchor.targets.float())["position_rmse_cm"]

    assert anchor_rmse(mixed_model) < 0.8 * anchor_rmse(plain_model)
    with pytest.raises(ConfigError, match="perception.anchor_dataset"):
        replace(mixed, model=PerceptionModelConfig(name="mlp", joint_inputs=16))


def test_a_temporal_model_keeps_fitting_the_anchor_s_episodes(tmp_path):
    """A temporal model's anchor is windows of another dataset's episodes (here: random motion),
    each update fitting them beside its own: it then reads those episodes better than without."""
    from tacgnn.datasets.baoding_data import BaodingDataConfig, generate
    from tacgnn.envs.baoding import BaodingEnv
    from tacgnn.perception.evaluation import metrics, predict
    from tacgnn.perception.models.temporal import MemoryConfig
    from tacgnn.perception.sequences import load_sequences
    from tacgnn.perception.train_config import PerceptionTrainConfig

    generate(BaodingDataConfig(samples=768, shard_size=768, num_envs=8, seed=5, settle_steps=0, keep_every=1,
                               scripted="random"), tmp_path / "anchor")
    anchor = load_sequences(tmp_path / "anchor")
    env = BaodingEnv(BaodingConfig(num_envs=16, obs_mode="perceived"))
    base = OnlinePerceptionConfig(model=PerceptionModelConfig(name="mlp"), temporal=True, window=4, burn_in=4,
                                  epochs=6, buffer_size=1024, batch_size=32, memory=MemoryConfig(feature=16, hidden=16))
    mixed = replace(base, anchor_dataset=str(tmp_path / "anchor"), anchor_share=0.5)
    plain_model, mixed_model = (OnlinePerception(c, to_dict(env.config.skin)) for c in (base, mixed))
    for model in (plain_model, mixed_model):
        model.bind_env(env)
    env.perception = plain_model
    env.reset(seed=0)
    still = env.last_action.copy()  # the env's own frames: a hand at rest, unlike the anchor's motion
    for _ in range(40):
        *_, info = env.step(still)
        mixed_model.record(info)
        plain_model.record(info)
    for model in (plain_model, mixed_model):
        model.update()
    scoring = PerceptionTrainConfig(split="episode")
    error = {name: metrics(predict(m.model, anchor), scoring, anchor)["position_rmse_cm"]
             for name, m in (("plain", plain_model), ("mixed", mixed_model))}
    assert error["mixed"] < 0.8 * error["plain"], error
    with pytest.raises(ConfigError, match="perception.anchor_dataset"):
        OnlinePerception(replace(mixed, window=500, buffer_size=2048), to_dict(env.config.skin))


def test_a_missing_anchor_dataset_is_refused_naming_the_key(tmp_path):
    cfg = OnlinePerceptionConfig(anchor_dataset=str(tmp_path / "nowhere"))
    with pytest.raises(ConfigError, match=r"perception.anchor_dataset: .*nowhere.*no dataset manifest"):
        OnlinePerception(cfg, to_dict(default_skin()))


def test_the_in_loop_perception_error_matches_each_frame_s_balls_in_the_better_order():
    from tacgnn.learning.evaluate import matched_squared_error

    true = np.array([[0.0, 0, 0, 1, 1, 1], [0, 0, 0, 1, 1, 1]])
    perceived = np.array([[1.0, 1, 1, 0, 0, 0.1], [0, 0, 0.2, 1, 1, 1]])  # swapped and off by 0.1; in order, 0.2
    assert matched_squared_error(perceived, true) == pytest.approx(0.01 + 0.04)


def test_export_puts_another_perception_of_the_same_network_into_a_blind_policy(tmp_path):
    """perception_from: the exported blind policy acts with that checkpoint's weights (its actor
    unchanged); a ground-truth policy, or a perception of another network, is refused."""
    from tacgnn.learning.checkpoint import CheckpointError, load_policy_file
    from tacgnn.learning.policy import SHIPPED_GROUND_TRUTH, SHIPPED_POLICY, export_policy, load_perception
    from tacgnn.perception.checkpoint import load_checkpoint as load_perception_checkpoint

    results = Path(__file__).resolve().parent.parent / "results"
    offline = results / "perception_mix" / "checkpoints" / "tacgnn32_temporal_mix9.pt"
    out = export_policy(SHIPPED_POLICY, tmp_path / "blind.pt", perception_from=offline)
    weights = load_perception_checkpoint(offline)["model"]
    acting = load_perception(out)
    assert acting is not None and all(torch.equal(acting.model.state_dict()[k], v) for k, v in weights.items())
    shipped, exported = load_policy_file(SHIPPED_POLICY), load_policy_file(out)
    assert all(torch.equal(v, exported["actor_state_dict"][k]) for k, v in shipped["actor_state_dict"].items())
    assert exported["perception"]["config"]["pretrained"] == str(offline)
    with pytest.raises(ConfigError, match="without a perception"):
        export_policy(SHIPPED_GROUND_TRUTH, tmp_path / "gt.pt", perception_from=offline)
    with pytest.raises(CheckpointError, match="differs .* in \\['temporal'"):
        export_policy(SHIPPED_POLICY, tmp_path / "x.pt",
                      perception_from=results / "real_hand" / "checkpoints" / "tacgnn32_skin_real.pt")


def test_ground_truth_export_is_the_blind_actor_reading_the_true_balls(tmp_path):
    """ground_truth: the blind policy's actor, unchanged, in a ground-truth env (no perception, no
    skin); it acts there as the blind policy's actor does on the same observation. A policy without a
    perception, or another perception beside it, is refused."""
    from tacgnn.learning.checkpoint import load_policy_file, stored_env_config
    from tacgnn.learning.evaluate import evaluate
    from tacgnn.learning.policy import SHIPPED_POLICY, export_policy, load_policy

    out = export_policy(SHIPPED_POLICY, tmp_path / "gt.pt", ground_truth=True)
    exported, blind = load_policy_file(out), load_policy_file(SHIPPED_POLICY)
    assert "perception" not in exported
    env = stored_env_config(exported, out)
    assert (env.obs_mode, env.tactile) == ("groundtruth", False)
    assert env.randomization == stored_env_config(blind, SHIPPED_POLICY).randomization
    obs = np.random.default_rng(0).standard_normal((5, 54)).astype(np.float32)
    assert np.array_equal(load_policy(out)[0](obs), load_policy(SHIPPED_POLICY)[0](obs))
    assert evaluate(out, episodes=2, num_envs=2)["episodes"] == 2
    with pytest.raises(ConfigError, match="without a perception"):
        export_policy(out, tmp_path / "again.pt", ground_truth=True)
    with pytest.raises(ConfigError, match="takes no perception"):
        export_policy(SHIPPED_POLICY, tmp_path / "x.pt", ground_truth=True, perception_from=SHIPPED_POLICY)
