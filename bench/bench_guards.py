"""What the NaN/Inf guards cost: the gradient-norm check per perception batch, and the
copy of models and optimiser that lets a bad PPO update be rolled back.

    .venv/bin/python bench/bench_guards.py [--checkpoint runs/gt_s0/model_001000.pt]
"""
import argparse
import copy
import time

import torch

from tacgnn.learning.checkpoint import load_checkpoint
from tacgnn.perception.models import PerceptionModelConfig, build_model
from tacgnn.user_errors import run_script


def per_call(fn, repeats: int) -> float:
    start = time.perf_counter()
    for _ in range(repeats):
        fn()
    return (time.perf_counter() - start) / repeats


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", default="", help="a PPO checkpoint (default: the default policy's sizes)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    model = build_model(PerceptionModelConfig(name="tacgnn"))
    grads = [torch.randn_like(p) for p in model.parameters()]
    seconds = per_call(lambda: torch.nn.utils.get_total_norm(grads), 2000)
    print(f"TacGNN-32 gradient norm ({len(grads)} tensors): {seconds * 1e6:.0f} us per batch; "
          f"{seconds * 10 * 25_000 / 32:.2f} s over 10 epochs x 25,000 samples at batch 32")
    if args.checkpoint:
        ckpt = load_checkpoint(args.checkpoint)
        state = {k: ckpt[k] for k in ("actor_state_dict", "critic_state_dict", "optimizer_state_dict")}
    else:  # the default policy's sizes, with the Adam moments a trained run holds
        import contextlib
        import io

        from tacgnn.envs.baoding import BaodingConfig
        from tacgnn.learning.config import PPOConfig
        from tacgnn.learning.rsl_env import RslBaodingEnv
        from tacgnn.learning.runner import make_runner

        with contextlib.redirect_stdout(io.StringIO()):  # rsl_rl prints the models
            runner = make_runner(RslBaodingEnv(BaodingConfig(num_envs=2, tactile=False)), PPOConfig(num_envs=2))
        for group in runner.alg.optimizer.param_groups:
            for p in group["params"]:
                p.grad = torch.zeros_like(p)
        runner.alg.optimizer.step()
        state = runner.alg.save()
    numel = sum(t.numel() for d in state.values() for t in _tensors(d))
    seconds = per_call(lambda: copy.deepcopy(state), 50)
    print(f"PPO update guard: copy of {numel * 4 / 1e6:.1f} MB of models and optimiser, "
          f"{seconds * 1e3:.1f} ms per update")


def _tensors(d):
    if isinstance(d, torch.Tensor):
        yield d
    elif isinstance(d, dict):
        for v in d.values():
            yield from _tensors(v)


if __name__ == "__main__":
    raise SystemExit(run_script(main))
