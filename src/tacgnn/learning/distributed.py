"""Data-parallel PPO over processes: one rank per GPU (nccl), or CPU processes (gloo).

torchrun starts the ranks and tells each one who it is (WORLD_SIZE, RANK, LOCAL_RANK,
MASTER_ADDR, MASTER_PORT):

    torchrun --standalone --nproc-per-node 4 -m tacgnn.cli train-policy --device cuda --run-dir runs/x ...

Every rank steps its own envs, seeded apart (`rank_seed`), so the ranks collect different
experience; rsl_rl's PPO averages the gradients of all ranks (all-reduce) before each
optimiser step and the KL of the adaptive schedule, and its observation normalisers pool
their statistics, so the networks stay the same on every rank. Rank 0 alone writes files.

rsl_rl's own runner assumes one GPU per rank (device ``cuda:LOCAL_RANK``, backend nccl); here
the backend follows the device, so the same run works on CPU processes with gloo, which is
how it is tested on a machine without a GPU.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

import torch
import torch.distributed as dist

from tacgnn.config import ConfigError

# Rank r's seeds are the run's seeds + r x SEED_STRIDE: rank 0 keeps the run's own seeds (a
# one-process run is unchanged), and runs whose seeds differ by less than this share no envs.
SEED_STRIDE = 10_000


@dataclass(frozen=True)
class Distributed:
    """Where this process stands in a (possibly one-process) training run.

    Attributes:
        world_size: number of processes (ranks).
        rank: this process's rank, 0..world_size-1; rank 0 writes the run's files.
        local_rank: rank on this machine; a GPU rank uses ``cuda:local_rank``.
        device: torch device of the policy and PPO ("cpu", "cuda:0", ...).
        backend: torch.distributed backend, "nccl" on GPUs, "gloo" on the CPU.
    """

    world_size: int = 1
    rank: int = 0
    local_rank: int = 0
    device: str = "cpu"
    backend: str = "gloo"

    @property
    def enabled(self) -> bool:
        return self.world_size > 1

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    def rsl_rl_cfg(self) -> dict[str, int] | None:
        """rsl_rl's ``multi_gpu`` entry: PPO all-reduces gradients when it is set."""
        if not self.enabled:
            return None
        return {"global_rank": self.rank, "local_rank": self.local_rank, "world_size": self.world_size}


def from_environment(device: str = "cpu", environ: dict[str, str] | None = None) -> Distributed:
    """The setup torchrun's variables describe, with `device` ('cpu', 'cuda' or 'cuda:N') checked.

    Under torchrun 'cuda' means ``cuda:LOCAL_RANK``. Raises ConfigError, naming the value, for
    a device that is not there or variables that do not fit together.
    """
    env = os.environ if environ is None else environ
    world_size, rank, local_rank = (_int_var(env, name, default) for name, default in
                                    (("WORLD_SIZE", 1), ("RANK", 0), ("LOCAL_RANK", 0)))
    if world_size < 1 or not 0 <= rank < world_size or not 0 <= local_rank < world_size:
        raise ConfigError(f"WORLD_SIZE={world_size}, RANK={rank}, LOCAL_RANK={local_rank}: need "
                          "0 <= RANK, LOCAL_RANK < WORLD_SIZE (launch with torchrun)")
    if world_size > 1:
        missing = [name for name in ("MASTER_ADDR", "MASTER_PORT") if not env.get(name)]
        if missing:
            raise ConfigError(f"WORLD_SIZE={world_size} but {' and '.join(missing)} not set: launch the ranks "
                              "with torchrun (torchrun --standalone --nproc-per-node N -m tacgnn.cli ...)")
    return Distributed(world_size, rank, local_rank, _resolve_device(device, world_size, local_rank),
                       "nccl" if device.startswith("cuda") else "gloo")


def _int_var(env: Any, name: str, default: int) -> int:
    value = env.get(name)
    if value is None or value == "":
        return default
    try:
        return int(value)
    except ValueError:
        raise ConfigError(f"{name}={value!r} is not an integer") from None


def _resolve_device(device: str, world_size: int, local_rank: int) -> str:
    if device == "cpu":
        return "cpu"
    if device != "cuda" and not (device.startswith("cuda:") and device[5:].isdigit()):
        raise ConfigError(f"--device {device!r}: expected 'cpu', 'cuda' or 'cuda:N'")
    if world_size > 1 and device != "cuda":
        raise ConfigError(f"--device {device!r} with WORLD_SIZE={world_size}: give 'cuda', each rank takes "
                          "cuda:LOCAL_RANK")
    if not torch.cuda.is_available():
        raise ConfigError(f"--device {device!r}: no CUDA device here (torch {torch.__version__}, "
                          f"CUDA build {torch.version.cuda or 'none'}); use --device cpu")
    index = local_rank if device == "cuda" else int(device[5:])
    count = torch.cuda.device_count()
    if index >= count:
        launched = f" (rank with LOCAL_RANK={local_rank} of WORLD_SIZE={world_size})" if world_size > 1 else ""
        raise ConfigError(f"--device {device!r}{launched} needs cuda:{index}, but this machine has {count} "
                          f"CUDA device(s): start at most {count} processes per node")
    return f"cuda:{index}"


def init(setup: Distributed) -> None:
    """Join the process group (blocks until every rank has joined); nothing for one process."""
    if not setup.enabled or dist.is_initialized():
        return
    if setup.device.startswith("cuda"):
        torch.cuda.set_device(torch.device(setup.device))
    dist.init_process_group(backend=setup.backend, rank=setup.rank, world_size=setup.world_size)


def shutdown(setup: Distributed) -> None:
    if setup.enabled and dist.is_initialized():
        dist.destroy_process_group()


def rank_seed(seed: int, setup: Distributed) -> int:
    """The seed of this rank's envs and random draws (rank 0: the run's seed)."""
    return seed + setup.rank * SEED_STRIDE


def gather_to_main(obj: Any, setup: Distributed) -> list[Any] | None:
    """Every rank's `obj`, in rank order, on rank 0 (None on the others); [obj] for one process."""
    if not setup.enabled:
        return [obj]
    gathered: list[Any] | None = [None] * setup.world_size if setup.is_main else None
    dist.gather_object(obj, gathered, dst=0)
    return gathered


def barrier(setup: Distributed) -> None:
    """Wait until every rank gets here (e.g. until rank 0 has written a checkpoint)."""
    if setup.enabled:
        dist.barrier()


def check_same(value: Any, what: str, setup: Distributed) -> None:
    """Raise ConfigError on every rank unless all ranks hold the same `value`."""
    if not setup.enabled:
        return
    values: list[Any] = [None] * setup.world_size
    dist.all_gather_object(values, value)
    if any(v != values[0] for v in values):
        raise ConfigError(f"the ranks differ in {what}: {', '.join(f'rank {r}: {v}' for r, v in enumerate(values))}")
