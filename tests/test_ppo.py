"""PPO wiring: the rsl_rl adapter, training runs, checkpoints, exact resume, evaluation, learning."""

import copy
import math
import shutil
from dataclasses import replace

import numpy as np
import pytest
import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from tacgnn.envs.baoding import BaodingConfig, BaodingEnv
from tacgnn.envs.observation import BALL_COLUMNS
from tacgnn.files import FileProblem
from tacgnn.learning.checkpoint import FORMAT_VERSION, CheckpointError, list_checkpoints, load_checkpoint
from tacgnn.learning.config import PPOConfig
from tacgnn.learning.evaluate import evaluate, seed_bootstrap_difference, wilson_interval
from tacgnn.learning.policy import load_policy
from tacgnn.learning.rsl_env import RslBaodingEnv
from tacgnn.learning.runner import Runner, make_runner
from tacgnn.learning.train import seed_everything, train

# Short episodes so that resets, time-outs and the episode log all happen in a few iterations.
ENV = BaodingConfig(tactile=False, max_episode_steps=12)


def ppo(iterations, **kw):
    return PPOConfig(num_envs=8, max_iterations=iterations, save_interval=100, **kw)


@pytest.fixture(scope="module")
def run2(tmp_path_factory):
    """A 2-iteration training run, shared by the tests that only read it."""
    run_dir = tmp_path_factory.mktemp("run2")
    train(ENV, ppo(2), run_dir)
    return run_dir


# --- (a) the adapter -------------------------------------------------------------------
def test_adapter_shapes_rewards_and_time_outs():
    cfg = BaodingConfig(num_envs=2, tactile=False, max_episode_steps=3)
    env, raw = RslBaodingEnv(cfg, reward_scale=0.01), BaodingEnv(cfg)
    raw_obs, _ = raw.reset(seed=cfg.seed)
    obs = env.get_observations()
    assert isinstance(env, VecEnv) and isinstance(obs, TensorDict)
    assert obs["policy"].shape == (2, 54) and obs["policy"].dtype == torch.float32
    assert np.array_equal(obs["policy"].numpy(), raw_obs)
    assert env.num_actions == 16 and env.num_obs == 54 and env.max_episode_length == 3

    actions = torch.from_numpy(raw.last_action.astype(np.float32))
    for t in range(1, 4):
        obs, rewards, dones, extras = env.step(actions)
        raw_obs, raw_reward, terminated, truncated, _ = raw.step(actions.numpy())
        assert rewards.shape == (2,) and rewards.dtype == torch.float32
        assert torch.allclose(rewards, torch.from_numpy(raw_reward) * 0.01)
        assert np.array_equal(obs["policy"].numpy(), raw_obs)  # after the same-step reset
        assert dones.shape == (2,) and extras["time_outs"].shape == (2,)
        assert dones.tolist() == (terminated | truncated).astype(int).tolist()
        if t < 3:
            assert not dones.any() and env.episode_length_buf.tolist() == [t, t]
            assert extras["log"] == {}
    assert extras["time_outs"].all() and dones.all()  # step 3: truncated, not terminated
    assert env.episode_length_buf.tolist() == [0, 0]  # new episodes
    log = extras["log"]
    assert log["Episode/timeout_rate"].tolist() == [1, 1] and log["Episode/length"].tolist() == [3, 3]
    assert {"Episode/success_rate", "Episode/fall_rate", "Episode/final_angle_deg",
            "Episode/return_rotation"} <= set(log)

    env.episode_length_buf = torch.tensor([2, 1])  # rsl_rl may assign it: it must reach the env
    assert env.env.episode_steps.tolist() == [2, 1]


def test_adapter_termination_is_done_but_not_time_out():
    # A ball "falls" as soon as it is more than 1 mm above the palm: every env terminates at once.
    env = RslBaodingEnv(BaodingConfig(num_envs=2, tactile=False, fall_height=(0.0, 0.001)))
    _, _, dones, extras = env.step(torch.zeros(2, 16))
    assert dones.tolist() == [1, 1] and not extras["time_outs"].any()
    assert extras["log"]["Episode/fall_rate"].tolist() == [1, 1]


def test_adapter_stops_on_an_infinite_observation():
    """A perception that returns Inf for env 1 stops the step with the env named (rsl_rl's own
    check catches NaN only), before anything reaches the normalisers."""
    calls = []

    def perception(tactile, taxel_pos):
        out = np.zeros((len(tactile), 6))
        out[1, 2] = np.inf if calls else 0.0  # finite at reset, Inf from the first step on
        calls.append(1)
        return out

    cfg = BaodingConfig(num_envs=3, obs_mode="perceived", track_balls=False)
    env = RslBaodingEnv(cfg, perception=perception)
    with pytest.raises(FloatingPointError, match=r"observation in envs \[1\].*columns \[34\]"):
        env.step(torch.zeros(3, 16))
    calls.clear()
    calls.append(1)  # Inf already at reset: the adapter refuses to start
    with pytest.raises(FloatingPointError, match="envs \\[1\\]"):
        RslBaodingEnv(cfg, perception=perception)


def test_adapter_rejects_dict_observations():
    with pytest.raises(ValueError, match="tactile"):
        RslBaodingEnv(BaodingConfig(num_envs=1, obs_mode="tactile"))


def test_ppo_config_defaults_and_rsl_rl_dict():
    cfg = PPOConfig()
    assert (cfg.num_envs, cfg.num_steps_per_env, cfg.num_learning_epochs) == (256, 8, 5)
    assert cfg.actor_hidden_dims == cfg.critic_hidden_dims == (512, 256, 128) and cfg.activation == "elu"
    assert (cfg.learning_rate, cfg.desired_kl, cfg.gamma, cfg.lam, cfg.clip_param) == (5e-3, 0.02, 0.99, 0.95, 0.2)
    assert (cfg.reward_scale, cfg.entropy_coef, cfg.init_noise_std, cfg.max_grad_norm) == (0.01, 0.0, 1.0, 1.0)
    d = cfg.rsl_rl_cfg()
    assert d["obs_groups"] == {"actor": ["policy"], "critic": ["policy"]}
    assert d["algorithm"]["schedule"] == "adaptive" and d["actor"]["obs_normalization"]
    with pytest.raises(ValueError, match="num_mini_batches"):
        PPOConfig(num_mini_batches=0)


# --- (b) a training run ----------------------------------------------------------------
def test_train_writes_config_checkpoint_and_events(run2):
    assert (run2 / "config.yaml").is_file()
    assert list(run2.glob("events.out.tfevents.*"))
    assert [p.name for p in list_checkpoints(run2)] == ["model_000001.pt", "model_000002.pt"]
    ckpt = torch.load(run2 / "model_000002.pt", weights_only=True)
    assert ckpt["iteration"] == 2 and ckpt["format_version"] == FORMAT_VERSION
    assert ckpt["env_config"]["obs_mode"] == "groundtruth" and ckpt["env_config"]["num_envs"] == 8
    assert ckpt["ppo_config"]["max_iterations"] == 2
    assert not list(run2.glob(".*.tmp"))

    policy, env_cfg = load_policy(run2 / "model_000002.pt")
    actions = policy(np.zeros((3, 54), np.float32))
    assert actions.shape == (3, 16) and np.array_equal(actions, policy(np.zeros((3, 54), np.float32)))
    assert env_cfg.max_episode_steps == 12


def test_fresh_run_refuses_a_used_run_dir(run2):
    with pytest.raises(FileExistsError, match="resume"):
        train(ENV, ppo(4), run2)


# --- (c) exact resume ------------------------------------------------------------------
def test_resume_continues_bit_for_bit(run2, tmp_path):
    straight, resumed = tmp_path / "straight", tmp_path / "resumed"
    train(ENV, replace(ppo(4), save_interval=3), straight)  # saves after the first, every 3rd and the last
    assert [p.name for p in list_checkpoints(straight)] == ["model_000001.pt", "model_000003.pt", "model_000004.pt"]
    shutil.copytree(run2, resumed)
    last = train(ENV, ppo(4), resumed, resume=True)
    assert last.name == "model_000004.pt"
    a, b = load_checkpoint(straight / "model_000004.pt"), load_checkpoint(last)
    assert b["iteration"] == 4
    for key in ("actor_state_dict", "critic_state_dict"):  # weights, std and normaliser statistics
        for name, tensor in a[key].items():
            assert torch.equal(tensor, b[key][name]), f"{key}.{name}"
    opt_a, opt_b = a["optimizer_state_dict"], b["optimizer_state_dict"]
    assert opt_a["param_groups"][0]["lr"] == opt_b["param_groups"][0]["lr"]
    for i, state in opt_a["state"].items():
        assert all(torch.equal(state[k], opt_b["state"][i][k]) for k in state)
    assert torch.equal(a["env_state"]["sim_state"], b["env_state"]["sim_state"])


def test_privileged_critic_reads_true_balls_and_resumes_exactly(tmp_path):
    """The actor sees noisy ball positions, the critic the true ones; a resumed run matches."""
    env_cfg = replace(ENV, obs_mode="noise_10")
    env = RslBaodingEnv(env_cfg, privileged_critic=True)
    obs = env.step(torch.zeros(env.num_envs, 16))[0]
    truth = env.env.ball_positions().reshape(-1, 6)
    np.testing.assert_allclose(obs["critic"][:, BALL_COLUMNS].numpy(), truth, atol=1e-6)
    assert np.abs(obs["policy"][:, BALL_COLUMNS].numpy() - truth).max() > 1e-3
    torch.testing.assert_close(obs["critic"][:, :32], obs["policy"][:, :32])  # same proprioception
    cfg = lambda n: replace(ppo(n), privileged_critic=True, save_interval=2)  # noqa: E731
    train(env_cfg, cfg(4), tmp_path / "straight")
    train(env_cfg, cfg(2), tmp_path / "resumed")
    train(env_cfg, cfg(4), tmp_path / "resumed", resume=True)
    a, b = load_checkpoint(tmp_path / "straight" / "model_000004.pt"), load_checkpoint(
        tmp_path / "resumed" / "model_000004.pt")
    for key in ("actor_state_dict", "critic_state_dict"):
        for name, tensor in a[key].items():
            assert torch.equal(tensor, b[key][name]), f"{key}.{name}"
    # the blind actor acts from the policy observation alone
    policy, _ = load_policy(tmp_path / "straight" / "model_000004.pt")
    assert policy(obs["policy"].numpy()).shape == (env.num_envs, 16)


# --- (d), (e) bad checkpoints ----------------------------------------------------------
def test_resume_with_another_obs_mode_names_it(run2, tmp_path):
    shutil.copytree(run2, tmp_path / "run")
    with pytest.raises(ValueError, match="obs_mode"):
        train(BaodingConfig(tactile=False, max_episode_steps=12, obs_mode="no_perception"), ppo(4),
              tmp_path / "run", resume=True)


def _run_without(run2, folder, section: str, key: str):
    """A copy of `run2` in `folder` whose checkpoint's `section` config lacks `key` (written before
    the key existed); returns that folder."""
    shutil.copytree(run2, folder)
    path = folder / "model_000002.pt"
    ckpt = torch.load(path, weights_only=True)
    del ckpt[section][key]
    torch.save(ckpt, path)
    return folder


def test_resume_accepts_config_keys_added_since(run2, tmp_path):
    """A checkpoint written before an env key existed resumes under that key's default, and not
    under another value."""
    run = _run_without(run2, tmp_path / "run", "env_config", "track_balls")
    assert train(ENV, ppo(3), run, resume=True).name == "model_000003.pt"
    with pytest.raises(ValueError, match="track_balls"):
        train(replace(ENV, track_balls=False), ppo(3), _run_without(run2, tmp_path / "run2", "env_config",
                                                                    "track_balls"), resume=True)


def test_a_checkpoint_from_before_the_action_distribution_key_resumes_as_gaussian(run2, tmp_path):
    run = _run_without(run2, tmp_path / "run", "ppo_config", "action_distribution")
    assert train(ENV, ppo(3), run, resume=True).name == "model_000003.pt"
    with pytest.raises(ValueError, match="action_distribution"):
        train(ENV, ppo(4, action_distribution="beta"), run, resume=True)


def test_a_beta_policy_acts_strictly_inside_the_range(run2, tmp_path):
    """Whatever it reads, a Beta policy's mean action stays inside (-1, 1) (a Gaussian's is clipped
    there), its file loads like any other, and a Gaussian checkpoint cannot start it."""
    path = train(ENV, ppo(2, action_distribution="beta"), tmp_path / "beta")
    act, _ = load_policy(path)
    gaussian, _ = load_policy(run2 / "model_000002.pt")
    dim = load_checkpoint(path)["obs_dim"]
    obs = np.random.default_rng(0).normal(0.0, 1e3, (64, dim)).astype(np.float32)  # far outside training's
    actions = act(obs)
    assert actions.shape == (64, 16) and (np.abs(actions) < 1).all() and actions.std() > 0
    assert (np.abs(gaussian(obs)) > 1).any()  # the Gaussian's mean leaves the range
    with pytest.raises(CheckpointError, match="action_distribution"):
        train(ENV, ppo(2, action_distribution="beta", init_from=str(run2 / "model_000002.pt")), tmp_path / "b2")


def test_truncated_checkpoint_is_named(run2, tmp_path):
    shutil.copytree(run2, tmp_path / "run")
    path = tmp_path / "run" / "model_000002.pt"
    path.write_bytes(path.read_bytes()[:1000])
    with pytest.raises(FileProblem, match="model_000002.pt"):
        load_checkpoint(path)
    with pytest.raises(FileProblem, match="model_000002.pt"):
        train(ENV, ppo(4), tmp_path / "run", resume=True)
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(FileProblem, match="junk.pt"):
        load_checkpoint(tmp_path / "junk.pt")
    torch.save({"weights": torch.zeros(2)}, tmp_path / "foreign.pt")  # readable, but not ours
    with pytest.raises(CheckpointError, match="foreign.pt"):
        load_checkpoint(tmp_path / "foreign.pt")


def _assert_same(a, b, where="checkpoint"):
    """Deep equality, key order and tensor dtypes included."""
    assert type(a) is type(b), where
    if isinstance(a, dict):
        assert list(a) == list(b), where
        for key in a:
            _assert_same(a[key], b[key], f"{where}.{key}")
    elif isinstance(a, (list, tuple)):
        assert len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _assert_same(x, y, f"{where}[{i}]")
    elif isinstance(a, torch.Tensor):
        assert a.dtype == b.dtype and torch.equal(a, b), where
    else:
        assert a == b, where


def test_save_load_save_gives_identical_bytes(run2, tmp_path):
    """Reliability test 6: a checkpoint restored into a fresh runner and written again holds the
    same tensor bytes and the same structure: the round trip loses or alters nothing.

    Only two archive members may differ: torch writes a random `serialization_id` per save, and
    the pickle memoises equal strings by object identity, which a load does not keep."""
    import zipfile

    path = run2 / "model_000002.pt"
    cfg, p = replace(ENV, num_envs=8), ppo(2)
    runner = Runner(RslBaodingEnv(cfg, p.reward_scale, p.bootstrap_time_outs), cfg, p, None)
    runner.restore(load_checkpoint(path))
    runner.save_checkpoint(tmp_path)
    again = tmp_path / "model_000002.pt"

    def members(file):
        with zipfile.ZipFile(file) as z:
            return {i.filename.split("/", 1)[1]: z.read(i) for i in z.infolist()}

    first, second = members(path), members(again)
    assert first.keys() == second.keys()
    differing = {name for name in first if first[name] != second[name]}
    assert differing <= {"data.pkl", ".data/serialization_id"}, differing
    _assert_same(torch.load(path, weights_only=True), torch.load(again, weights_only=True))


def test_non_finite_gradient_rolls_the_update_back_and_names_it(run2, tmp_path, monkeypatch):
    """Reliability item 3: an infinite gradient must not reach the weights or a checkpoint."""
    from rsl_rl.algorithms import PPO

    resumed = tmp_path / "resumed"
    shutil.copytree(run2, resumed)
    seen = []  # (algorithm, its state just before the poisoned update)
    real_update, real_clip = PPO.update, torch.nn.utils.clip_grad_norm_

    def recording_update(self):
        seen.append((self, copy.deepcopy(self.save())))
        return real_update(self)

    def poisoned_clip(params, *args, **kwargs):  # rsl_rl clips after backward, before the step
        params = list(params)
        if len(seen) == 2:  # the second update after resuming: the run's fourth
            params[0].grad.view(-1)[0] = float("inf")
        return real_clip(params, *args, **kwargs)

    monkeypatch.setattr(PPO, "update", recording_update)
    monkeypatch.setattr(torch.nn.utils, "clip_grad_norm_", poisoned_clip)
    message = r"PPO update 4: non-finite gradient .*\(actor .*rolled back.*model_000002"
    with pytest.raises(FloatingPointError, match=message):
        train(ENV, ppo(4), resumed, resume=True)
    alg, before = seen[-1]
    after = alg.save()
    for key in ("actor_state_dict", "critic_state_dict"):
        for name, tensor in before[key].items():
            assert torch.equal(tensor, after[key][name]), f"{key}.{name}"
    for i, state in before["optimizer_state_dict"]["state"].items():
        assert all(torch.equal(state[k], after["optimizer_state_dict"]["state"][i][k]) for k in state)
    assert [p.name for p in list_checkpoints(resumed)] == ["model_000001.pt", "model_000002.pt"]
    actor = load_checkpoint(resumed / "model_000002.pt")["actor_state_dict"]
    assert all(torch.isfinite(t).all() for t in actor.values())


def test_failed_save_leaves_no_partial_file(run2, tmp_path, monkeypatch):
    shutil.copytree(run2, tmp_path / "run")

    def broken_save(obj, fh, *args, **kw):
        fh.write(b"partial")
        raise OSError("disk full")

    monkeypatch.setattr(torch, "save", broken_save)
    with pytest.raises(FileProblem, match="cannot write .*model_000003.pt"):
        train(ENV, ppo(3), tmp_path / "run", resume=True)
    assert [p.name for p in list_checkpoints(tmp_path / "run")] == ["model_000001.pt", "model_000002.pt"]
    assert not list((tmp_path / "run").glob(".*.tmp"))


# --- evaluation ------------------------------------------------------------------------
def test_evaluate_counts_quota_per_env(run2):
    out = evaluate(run2 / "model_000002.pt", task="simple", episodes=5, num_envs=2, seed=1)
    assert out["episodes"] == 5 and 0.0 <= out["success_rate"] <= 1.0
    lo, hi = out["ci95"]
    assert 0.0 <= lo <= out["success_rate"] <= hi <= 1.0
    assert 0.0 <= out["fall_rate"] <= 1.0


def test_evaluate_on_another_hand(run2, tmp_path):
    """Env changes at evaluation apply (a fall radius of 1 mm ends every episode as a fall at once)
    and a bad key is named; the CLI writes every 180-degree task as JSON."""
    from tacgnn.config import ConfigError
    from tacgnn.learning.evaluate import TASKS_180
    from tacgnn.learning.evaluate import main as evaluate_main

    out = evaluate(run2 / "model_000002.pt", episodes=4, num_envs=2, env_overrides={"fall_radius": 0.001})
    assert out["fall_rate"] == 1.0 and out["success_rate"] == 0.0
    with pytest.raises(ConfigError, match="hand.stifness"):
        evaluate(run2 / "model_000002.pt", episodes=2, num_envs=2, env_overrides={"hand.stifness": 2.0})
    assert evaluate_main([str(run2 / "model_000002.pt"), "--episodes", "2", "--envs", "2", "--out",
                          str(tmp_path / "r.json"), "--set", "hand.stiffness=2.5"]) == 0
    import json
    rows = json.loads((tmp_path / "r.json").read_text())
    assert [r["task"] for r in rows] == list(TASKS_180)
    assert rows[0]["env_overrides"] == {"hand.stiffness": 2.5}


def test_wilson_interval():
    lo, hi = wilson_interval(45, 50)  # p = 0.9
    assert lo == pytest.approx(0.7864, abs=1e-3) and hi == pytest.approx(0.9565, abs=1e-3)
    assert wilson_interval(0, 10)[0] == 0.0 and wilson_interval(10, 10)[1] == 1.0


def test_seed_bootstrap_difference():
    # one seed per side: the episode noise alone, close to the normal interval of a difference
    diff, lo, hi = seed_bootstrap_difference([(461, 512)], [(410, 512)])
    half = 1.96 * math.sqrt(0.9 * 0.1 / 512 + 0.8 * 0.2 / 512)
    assert diff == pytest.approx(51 / 512)
    assert lo == pytest.approx(diff - half, abs=0.006) and hi == pytest.approx(diff + half, abs=0.006)
    # seeds that disagree: equal pooled rates, but a far wider interval than the episodes give
    diff, lo, hi = seed_bootstrap_difference([(500, 512), (300, 512)], [(400, 512), (400, 512)])
    assert diff == 0.0 and lo < -0.15 and hi > 0.15
    # every seed of one side far above every seed of the other: the interval excludes 0
    _, lo, _ = seed_bootstrap_difference([(460, 512), (450, 512), (470, 512)], [(300, 512), (320, 512)])
    assert lo > 0.2
    with pytest.raises(ValueError, match="successes <= episodes"):
        seed_bootstrap_difference([(600, 512)], [(1, 512)])
    with pytest.raises(ValueError, match="at least one seed"):
        seed_bootstrap_difference([], [(1, 512)])


# --- (f) PPO learns --------------------------------------------------------------------
class Reach1D(VecEnv):
    """x <- x + 0.1 clip(a, -1, 1), reward -|x - g|, 20-step episodes, obs (x, g); x, g ~ U(-1, 1)."""

    def __init__(self, n: int, seed: int):
        self.num_envs, self.num_actions, self.max_episode_length = n, 1, 20
        self.device, self.cfg = "cpu", {}
        self.gen = torch.Generator().manual_seed(seed)
        self.x, self.g = torch.zeros(n), torch.zeros(n)
        self.episode_length_buf = torch.zeros(n, dtype=torch.long)
        self._reset(torch.ones(n, dtype=torch.bool))

    def _reset(self, ids):
        self.x[ids] = torch.rand(int(ids.sum()), generator=self.gen) * 2 - 1
        self.g[ids] = torch.rand(int(ids.sum()), generator=self.gen) * 2 - 1
        self.episode_length_buf[ids] = 0

    def get_observations(self):
        return TensorDict({"policy": torch.stack([self.x, self.g], 1)}, batch_size=[self.num_envs])

    def step(self, actions):
        self.x = self.x + 0.1 * actions[:, 0].clamp(-1, 1)
        self.episode_length_buf += 1
        reward = -(self.x - self.g).abs()
        time_out = self.episode_length_buf >= self.max_episode_length
        self._reset(time_out)
        return self.get_observations(), reward, time_out.long(), {"time_outs": time_out}


def mean_reward(policy) -> float:
    env, total = Reach1D(256, seed=123), 0.0
    with torch.inference_mode():
        for _ in range(env.max_episode_length):
            _, reward, _, _ = env.step(policy(env.get_observations()))
            total += reward.mean().item()
    return total / env.max_episode_length


def test_ppo_learns_to_reach():
    seed_everything(0)
    cfg = PPOConfig(num_envs=64, num_steps_per_env=16, actor_hidden_dims=(32, 32), critic_hidden_dims=(32, 32),
                    learning_rate=1e-3, desired_kl=0.01, init_noise_std=0.5, reward_scale=1.0)
    runner = make_runner(Reach1D(64, seed=0), cfg)
    before = mean_reward(runner.get_inference_policy())
    runner.learn(40)
    after = mean_reward(runner.get_inference_policy())
    assert before < -0.55 and after > -0.3, (before, after)  # staying put scores about -2/3
