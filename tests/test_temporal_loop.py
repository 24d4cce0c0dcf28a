"""Temporal perception in the RL loop: one state per env, reset at each episode's start, trained on
windows of recorded frames, resumed bit for bit, and bad inputs named."""

import numpy as np
import pytest
import torch

from tacgnn.config import ConfigError, to_dict
from tacgnn.envs.baoding import BaodingConfig, BaodingEnv
from tacgnn.envs.observation import BALL_COLUMNS
from tacgnn.learning.checkpoint import frames_path, load_checkpoint
from tacgnn.learning.online_perception import OnlinePerception, OnlinePerceptionConfig
from tacgnn.learning.train import train
from tacgnn.perception.models import PerceptionModelConfig
from tacgnn.perception.models.temporal import MemoryConfig
from tests.test_kill_resume import _assert_identical

LOOP = OnlinePerceptionConfig(model=PerceptionModelConfig(name="mlp"), temporal=True, window=4, burn_in=4,
                              update_every_steps=8, epochs=1, buffer_size=64, batch_size=8, warmup_rounds=1,
                              memory=MemoryConfig(feature=16, hidden=16))


def _run(run_dir, iterations, resume=False):
    from tacgnn.learning.config import PPOConfig

    env = BaodingConfig(obs_mode="perceived", task="middle", max_episode_steps=12)
    ppo = PPOConfig(num_envs=4, num_steps_per_env=4, max_iterations=iterations, save_interval=100,
                    num_learning_epochs=2, num_mini_batches=2, actor_hidden_dims=(16,), critic_hidden_dims=(16,))
    return train(env, ppo, run_dir, resume=resume, perception_cfg=LOOP)


def test_temporal_perception_trains_in_the_loop_and_resumes_bit_for_bit(tmp_path):
    """3 iterations, stop, 3 more == 6 straight: weights, the per-env filter states and episode
    counters, the frame buffer with its episodes and steps, all bit for bit."""
    straight = _run(tmp_path / "straight", 6)
    _run(tmp_path / "resumed", 3)
    resumed = _run(tmp_path / "resumed", 6, resume=True)
    a, b = load_checkpoint(straight), load_checkpoint(resumed)
    assert a["perception"]["updates"] == 1 + 3  # the warm-up round, then every 2 iterations
    assert a["perception"]["env_state"].shape == (4, 16 + 6) and a["perception"]["episode_of_env"].max() >= 4
    _assert_identical(a, b)
    runs = (tmp_path / "straight", tmp_path / "resumed")
    frames = [torch.load(frames_path(run, 6), weights_only=True) for run in runs]
    assert frames[0]["frames"]["size"] == 64 and (frames[0]["frames"]["step"] >= 1).all()
    _assert_identical(*frames, where="frames")

    # the blind policy acts with its temporal perception (bound to the evaluation env)
    from tacgnn.learning.evaluate import evaluate

    result = evaluate(straight, "simple", episodes=4, num_envs=4)
    assert 0.0 <= result["success_rate"] <= 1.0


def test_state_is_per_env_and_starts_fresh_with_each_episode():
    """What the env is told at each step equals the model run over that env's episode so far (from
    its first step after the reset); envs that reset start again from the fresh state."""
    env = BaodingEnv(BaodingConfig(num_envs=3, obs_mode="perceived", max_episode_steps=5))
    perception = OnlinePerception(LOOP, to_dict(env.config.skin))
    perception.bind_env(env)
    env.perception = perception
    inputs = []
    call = perception.model.step

    def spy(readings, positions, joints, actions, state):
        inputs.append((readings.clone(), positions.clone(), joints.clone(), actions.clone()))
        return call(readings, positions, joints, actions, state)

    perception.model.step = spy
    env.reset(seed=0)
    history, outputs = {i: [] for i in range(3)}, []
    rng = np.random.default_rng(0)
    for _ in range(8):
        inputs.clear()
        obs, *_, info = env.step(rng.uniform(-0.3, 0.3, (3, 16)))
        r, p, j, a = inputs[0]  # the all-env call of this step; a second call reads the reset frames
        for i in range(3):
            history[i].append((r[i], p[i], j[i], a[i]))
        outputs.append(info["final_obs"][:, BALL_COLUMNS] if "final_obs" in info else obs[:, BALL_COLUMNS])
        if len(inputs) > 1:  # envs reset at steps 5: the state of each is fresh again
            assert (env.episode_steps == 0).all()
            assert torch.equal(perception.state, perception.model.initial_state(3))
            ended = {i: history[i] for i in range(3)}
            history = {i: [] for i in range(3)}
    assert len(ended[0]) == 5 and len(history[0]) == 3
    with torch.no_grad():  # the last 3 steps: the episode from its first frame, fresh state
        seq = [torch.stack([f[k] for f in history[1]]).unsqueeze(0) for k in range(4)]
        expected, _ = perception.model(*seq)
    got = np.stack(outputs[-3:])[:, 1]  # the env may swap the two balls (identity tracking): compare as sets
    assert np.allclose(np.sort(got, axis=1), np.sort(expected[0].numpy() / 100.0, axis=1), atol=1e-6)


def test_bad_inputs_are_named(tmp_path):
    skin = to_dict(BaodingConfig().skin)
    perception = OnlinePerception(LOOP, skin)
    with pytest.raises(RuntimeError, match="bind it first"):
        perception(np.zeros((2, 653), np.float32), np.zeros((2, 653, 3), np.float32), np.zeros((2, 16)))
    with pytest.raises(ConfigError, match="record_every"):
        OnlinePerceptionConfig(temporal=True, record_every=2)
    with pytest.raises(ConfigError, match="perception.model.name"):
        OnlinePerceptionConfig(temporal=True, model=PerceptionModelConfig(name="gcn"))
    # a single-frame checkpoint as a temporal perception's start, and a temporal one as a single-frame start
    from tacgnn.perception.train_config import TEMPORAL_ROUTE, PerceptionTrainConfig

    for temporal in (False, True):
        cfg = PerceptionTrainConfig.for_task("baoding", "mlp", **(TEMPORAL_ROUTE if temporal else {}))
        path, _ = _perception_checkpoint(tmp_path / f"{temporal}.pt", cfg)
        kind = "temporal" if temporal else "single-frame"
        with pytest.raises(ConfigError, match=f"a {kind} perception checkpoint; perception.temporal is "
                                              f"{str(not temporal).lower()}"):
            OnlinePerception(OnlinePerceptionConfig(temporal=not temporal, model=PerceptionModelConfig(name="mlp"),
                                                    pretrained=str(path)), skin)


def _perception_checkpoint(path, cfg):
    """A checkpoint of the model of `cfg` as `train-perception` writes it (weights as initialised)."""
    from tacgnn.perception.checkpoint import build_perception, save_checkpoint

    torch.manual_seed(1)
    model = build_perception(cfg.model, cfg.temporal, cfg.memory)
    save_checkpoint(path, {"config": to_dict(cfg), "epoch": 0, "model": model.state_dict(), "optimizer": {},
                           "history": [], "dataset": {"num_taxels": 653}, "rest_positions_cm": None})
    return path, model


@pytest.mark.parametrize("temporal", [True, False])
def test_evaluate_takes_sequence_checkpoints_as_perception(tmp_path, temporal):
    """`tacgnn evaluate --perception` with a temporal checkpoint gives a filter per env; with a
    --by-episode one the single-frame model itself, with its trained weights."""
    from tacgnn.learning.evaluate import perception_from_file
    from tacgnn.perception.train_config import TEMPORAL_ROUTE, PerceptionTrainConfig

    cfg = PerceptionTrainConfig.for_task("baoding", "mlp", memory=MemoryConfig(feature=8, hidden=8),
                                         **(TEMPORAL_ROUTE if temporal else {"split": "episode"}))
    path, model = _perception_checkpoint(tmp_path / "seq.pt", cfg)
    perception = perception_from_file(path, to_dict(BaodingConfig().skin))
    assert perception.temporal == temporal
    for name, tensor in model.state_dict().items():
        assert torch.equal(perception.model.state_dict()[name], tensor), name
    if not temporal:
        readings, positions = torch.rand(2, 653), torch.rand(2, 653, 3)
        with torch.no_grad():
            expected = model(readings, positions).numpy() / 100.0
        got = perception(readings.numpy(), positions.numpy() / 100.0)
        assert np.allclose(got, expected, atol=1e-6)
