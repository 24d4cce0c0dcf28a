"""Speed of the perception models on synthetic tactile frames.

Prints:
  * TacGNN-32 inference graphs/s at batch 256, ~60 activated taxels per frame,
    with 2 and 1 torch threads (target >= 20,000 graphs/s);
  * TacGNN-32 training time for 10 epochs x 25,000 samples at batch 32 with
    Adam (target < 2 min); by default one epoch is measured and x10 is an
    extrapolation, ``--full`` runs all 10 epochs;
  * MLP / CNN / GCN inference graphs/s at batch 256.

Synthetic frames: a fixed random 653-taxel cloud (a 20 x 10 x 4 cm box),
each frame translated by a random offset (the hand moving) and touched by
two balls that each activate the ~30 taxels nearest to a random taxel.

Usage: ``python bench/bench_perception.py [--full] [--profile]``
"""

from __future__ import annotations

import argparse
import time

import torch

from tacgnn.perception.models import PerceptionModelConfig, build_model

T = 653


def make_frames(n: int, rest: torch.Tensor, per_blob: int = 30, seed: int = 0):
    """``n`` frames: readings (n, T), per-frame offsets (n, 3), targets (n, 6) = blob centroids."""
    g = torch.Generator().manual_seed(seed)
    readings, targets = torch.zeros(n, T), torch.zeros(n, 6)
    d_rest = torch.cdist(rest, rest)
    for lo in range(0, n, 4096):  # chunks keep the (chunk, T) index tensors small
        hi = min(n, lo + 4096)
        for blob in range(2):
            centre = torch.randint(0, T, (hi - lo,), generator=g)
            size = torch.randint(per_blob - 8, per_blob + 9, (hi - lo,), generator=g)
            order = d_rest[centre].argsort(1)  # taxels by distance to the contact centre
            hit = (torch.arange(T).unsqueeze(0) < size.unsqueeze(1)).float()
            force = hit * (torch.rand(hi - lo, T, generator=g) + 0.1)
            blob_r = torch.zeros(hi - lo, T).scatter_(1, order, force)
            readings[lo:hi] = torch.maximum(readings[lo:hi], blob_r)
            w = torch.zeros(hi - lo, T).scatter_(1, order, hit)
            targets[lo:hi, 3 * blob : 3 * blob + 3] = (w @ rest) / size.unsqueeze(1)
    offsets = torch.randn(n, 3, generator=g) * 2.0
    return readings, offsets, targets + offsets.repeat(1, 2)


def graphs_per_second(model, readings, positions, min_time: float = 1.5) -> float:
    model.eval()
    with torch.inference_mode():
        for _ in range(3):
            model(readings, positions)
        n, t0 = 0, time.perf_counter()
        while time.perf_counter() - t0 < min_time:
            model(readings, positions)
            n += 1
        return n * readings.shape[0] / (time.perf_counter() - t0)


def train_time(model, readings, offsets, targets, rest, epochs: float, batch: int = 32) -> float:
    """Seconds for ``epochs`` passes over the data (shuffled, Adam, MSE)."""
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    model.train()
    N = readings.shape[0]
    steps = int(round(epochs * N / batch))
    perm = torch.cat([torch.randperm(N) for _ in range(int(epochs) + 1)])
    t0 = time.perf_counter()
    for s in range(steps):
        idx = perm[s * batch : (s + 1) * batch]
        pos = rest + offsets[idx].unsqueeze(1)
        loss = torch.nn.functional.mse_loss(model(readings[idx], pos), targets[idx])
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--full", action="store_true", help="train all 10 epochs instead of extrapolating 1")
    ap.add_argument("--profile", action="store_true", help="print a torch.profiler table of TacGNN inference")
    args = ap.parse_args()

    torch.manual_seed(0)
    rest = torch.rand(T, 3) * torch.tensor([20.0, 10.0, 4.0])
    readings, offsets, targets = make_frames(256, rest)
    positions = rest + offsets.unsqueeze(1)
    active = (readings > 0).sum(1).float()
    print(f"frames: batch 256, activated taxels per frame mean {active.mean():.1f} max {active.max():.0f}")

    tacgnn = build_model(PerceptionModelConfig(name="tacgnn", channels=32))
    for threads in (2, 1):
        torch.set_num_threads(threads)
        gps = graphs_per_second(tacgnn, readings, positions)
        print(f"TacGNN-32 inference, batch 256, {threads} thread(s): {gps:,.0f} graphs/s")

    torch.set_num_threads(1)
    if args.profile:
        from torch.profiler import ProfilerActivity, profile

        with torch.inference_mode(), profile(activities=[ProfilerActivity.CPU]) as prof:
            for _ in range(10):
                tacgnn(readings, positions)
        print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=20))

    for name in ("mlp", "cnn", "gcn"):
        model = build_model(name, rest_positions=rest)
        gps = graphs_per_second(model, readings, positions, min_time=1.0)
        print(f"{name.upper()} inference, batch 256, 1 thread: {gps:,.0f} graphs/s")

    torch.set_num_threads(2)
    n_train = 25_000
    tr, off, tg = make_frames(n_train, rest, seed=1)
    model = build_model(PerceptionModelConfig(name="tacgnn", channels=32))
    train_time(model, tr, off, tg, rest, epochs=0.02)  # warm-up
    epochs = 10.0 if args.full else 1.0
    secs = train_time(model, tr, off, tg, rest, epochs=epochs)
    label = "measured" if args.full else f"EXTRAPOLATED x10 from 1 measured epoch ({secs:.1f} s)"
    print(f"TacGNN-32 training, 10 epochs x {n_train:,} samples, batch 32, Adam, 2 threads: "
          f"{secs * 10 / epochs:.1f} s ({label})")


if __name__ == "__main__":
    main()
