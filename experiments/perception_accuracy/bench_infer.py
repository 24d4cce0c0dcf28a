"""TacGNN inference speed (graphs/s, batch 256, 1 thread) of configs, on bench_perception's frames.

    .venv/bin/python experiments/perception_accuracy/bench_infer.py [key=value ...] [-- key=value ...]

Each group of key=value model-config overrides (separated by --) is one config; no args =
the default config. 1 torch thread only (the other core is someone else's).
"""
import sys
from pathlib import Path

import torch

torch.set_num_threads(1)
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
from bench_perception import graphs_per_second, make_frames  # noqa: E402

from tacgnn.config import override, parse_overrides  # noqa: E402
from tacgnn.perception.models import PerceptionModelConfig, build_model, keep_freed_memory  # noqa: E402

keep_freed_memory()
torch.manual_seed(0)
rest = torch.rand(653, 3) * torch.tensor([20.0, 10.0, 4.0])
readings, offsets, _ = make_frames(256, rest)
positions = rest + offsets.unsqueeze(1)
groups, cur = [], []
for a in sys.argv[1:]:
    if a == "--":
        groups.append(cur); cur = []
    else:
        cur.append(a)
groups.append(cur)
for g in groups:
    cfg = override(PerceptionModelConfig(name="tacgnn"), parse_overrides(g))
    model = build_model(cfg)
    best, med = graphs_per_second(model, readings, positions)
    print(f"{' '.join(g) or 'defaults':70s} {best:8,.0f} graphs/s best (median {med:,.0f})", flush=True)
