"""The robustness table: a policy on hands and skins that differ the way real ones do.

    tacgnn evaluate POLICY --robustness [--episodes 512]

Each row changes one thing from the nominal hand (the randomisation ranges collapsed onto the
nominal values, `RandomizationConfig.nominal`) to an end of its range, on the skin the policy was
trained with; then "a real hand": every range of the default randomisation drawn per episode,
the real skin. Two rows say what the skin is worth: the skin dead (every taxel reads 0) on the
nominal hand and on a real hand. Success on Simple unless told; the last rows repeat "a real
hand" on Middle, Hard and the 1 s hold.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tacgnn.config import ConfigError, to_dict
from tacgnn.envs.randomization import RandomizationConfig
from tacgnn.files import atomic_write_text, check_writable
from tacgnn.learning import checkpoint as ckpt
from tacgnn.learning.evaluate import evaluate
from tacgnn.provenance import file_sha256, provenance


@dataclass(frozen=True)
class Row:
    name: str
    randomization: dict[str, Any] | None  # changes from the nominal hand; None: the default ranges
    skin: dict[str, Any]  # skin_signal keys
    task: str = "simple"


_SKIN_DEAD = {"dead_fraction": [1.0, 1.0]}
HAND_ROWS = (
    ("damping x0.3", {"damping_scale": (0.3, 0.3)}), ("damping x3", {"damping_scale": (3.0, 3.0)}),
    ("stiffness x0.75", {"stiffness_scale": (0.75, 0.75)}), ("stiffness x1.5", {"stiffness_scale": (1.5, 1.5)}),
    ("torque limit x0.8", {"torque_limit_scale": (0.8, 0.8)}),
    ("torque limit x1.2", {"torque_limit_scale": (1.2, 1.2)}),
    ("joint friction 0.03 N m", {"joint_friction": (0.03, 0.03)}),
    ("armature x0.5", {"armature_scale": (0.5, 0.5)}), ("armature x2", {"armature_scale": (2.0, 2.0)}),
    ("action latency 40 ms", {"action_latency": (0.04, 0.04)}),
    ("joint reading latency 20 ms", {"joint_latency": (0.02, 0.02)}),
    ("skin latency 20 ms", {"skin_latency": (0.02, 0.02)}),
    ("backlash 0.02 rad", {"backlash": (0.02, 0.02)}),
    ("encoder bias +0.01 rad, noise", {"joint_bias": (0.01, 0.01), "joint_noise": 0.005, "velocity_noise": 0.1}),
    ("encoder bias -0.01 rad, noise", {"joint_bias": (-0.01, -0.01), "joint_noise": 0.005, "velocity_noise": 0.1}),
    ("action noise 0.05", {"action_noise": 0.05}),
    ("gravity 7 m/s^2", {"gravity": (7.0, 7.0)}), ("gravity 12 m/s^2", {"gravity": (12.0, 12.0)}),
    ("ball mass 0.075 kg", {"ball_mass": (0.075, 0.075)}), ("ball mass 0.225 kg", {"ball_mass": (0.225, 0.225)}),
    ("friction x0.7", {"friction_scale": (0.7, 0.7)}), ("friction x1.3", {"friction_scale": (1.3, 1.3)}),
)
SKIN_ROWS = (
    ("skin: ideal", {"preset": "ideal"}),
    ("skin: noise floor 0.02 N", {"noise_floor": 0.02}),
    ("skin: 10 % dead, 1 % stuck", {"dead_fraction": [0.1, 0.1], "stuck_fraction": [0.01, 0.01]}),
    ("skin: calibrated 60 s before", {"calibration_age": [60.0, 60.0]}),
    ("skin: crosstalk 0.1, relaxation 0.2", {"crosstalk": 0.1, "relaxation": 0.2}),
)


def rows(uses_skin: bool) -> list[Row]:
    """The table's rows; the skin's rows only for a policy that reads the skin."""
    out = [Row("nominal", {}, {})]
    out += [Row(name, changes, {}) for name, changes in HAND_ROWS if uses_skin or "skin_latency" not in changes]
    if uses_skin:
        out += [Row(name, {}, skin) for name, skin in SKIN_ROWS]
    out.append(Row("a real hand", None, {}))
    if uses_skin:
        out += [Row("skin dead, nominal hand", {}, _SKIN_DEAD), Row("skin dead, a real hand", None, _SKIN_DEAD)]
    out += [Row(f"a real hand, {task}", None, {}, task) for task in ("middle", "hard", "hold")]
    return out


def overrides(row: Row, ball_mass: float) -> dict[str, Any]:
    """The env config changes (dotted keys) of `row`."""
    if row.randomization is None:
        randomization = RandomizationConfig(enabled=True)
    else:
        randomization = RandomizationConfig.nominal(ball_mass, **row.randomization)
    changes: dict[str, Any] = {"randomization": to_dict(randomization)}
    changes.update({f"skin_signal.{key}": value for key, value in row.skin.items()})
    return changes


def robustness_table(checkpoint: str | Path, stored_env: Any, episodes: int, num_envs: int, seed: int,
                     progress: Any = print, done: dict[str, dict[str, Any]] | None = None,
                     after_row: Any = None) -> list[dict[str, Any]]:
    """Evaluate `checkpoint` on every row; one result dict per row (`evaluate`'s, plus 'row').

    Rows in `done` (by name) are taken as they are; `after_row(results)` is called after each new
    row, so that an interrupted table loses at most the row under way.
    """
    uses_skin = stored_env.obs_mode in ("perceived", "tactile")
    results = []
    for row in rows(uses_skin):
        if done and row.name in done:
            results.append(done[row.name])
            continue
        result = evaluate(checkpoint, row.task, episodes, num_envs, seed,  # type: ignore[arg-type]
                          env_overrides=overrides(row, stored_env.ball_mass))
        result["row"] = row.name
        progress(f"  {row.name:<36} {row.task:<7} {100 * result['success_rate']:5.1f} %  "
                 f"(falls {100 * result['fall_rate']:.1f} %)")
        results.append(result)
        if after_row is not None:
            after_row(results)
    return results


def markdown(results: list[dict[str, Any]]) -> str:
    """The table as markdown: row, task, success with its 95 % interval, falls."""
    lines = ["| change | task | success % (95 % CI) | falls % |", "| --- | --- | --- | --- |"]
    for r in results:
        lo, hi = r["ci95"]
        lines.append(f"| {r['row']} | {r['task']} | {100 * r['success_rate']:.1f} ({100 * lo:.1f}-{100 * hi:.1f}) "
                     f"| {100 * r['fall_rate']:.1f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None, parser_class: type[argparse.ArgumentParser] = argparse.ArgumentParser) -> int:
    """`tacgnn robustness`; user errors raise (ConfigError, CheckpointError, OSError), for the CLI to report."""
    parser = parser_class(prog="tacgnn robustness",
                          description="A policy on hands and skins that differ as real ones do: one change at a "
                                      "time at the ends of the randomisation ranges, then a real hand.")
    parser.add_argument("checkpoint", type=Path, help="a policy checkpoint (train-policy) or a shipped policy")
    parser.add_argument("--episodes", type=int, default=512, help="episodes per row (default: %(default)s)")
    parser.add_argument("--envs", type=int, default=128, help="envs stepped together (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=0, help="evaluation seed (default: %(default)s)")
    parser.add_argument("--out", type=Path, help="also write the rows as JSON here, and the table beside it (.md)")
    args = parser.parse_args(argv)
    for flag, value in (("--episodes", args.episodes), ("--envs", args.envs)):
        if value < 1:
            raise ConfigError(f"{flag} must be >= 1, got {value}")
    if args.out is not None:
        check_writable(args.out.parent)  # before the hour of evaluation, not after it
    stored = ckpt.stored_env_config(ckpt.load_policy_file(args.checkpoint), args.checkpoint)
    print(f"{args.checkpoint}: {args.episodes} episodes per row, deterministic policy")
    settings = {"episodes": args.episodes, "envs": args.envs}
    done = _finished_rows(args.out, args.checkpoint, args.seed, settings) if args.out is not None else {}

    def save(results: list[dict[str, Any]]) -> None:
        for r in results:
            r.setdefault("provenance", provenance({"policy": args.checkpoint}, args.seed,
                                                  {"row": r["row"], "task": r["task"], **settings}))
        atomic_write_text(args.out, json.dumps(results, indent=2))
        atomic_write_text(args.out.with_suffix(".md"), markdown(results))

    results = robustness_table(args.checkpoint, stored, args.episodes, args.envs, args.seed, done=done,
                               after_row=save if args.out is not None else None)
    if args.out is not None:
        save(results)  # the table as this version's rows make it, also when every row was done
    print(markdown(results), end="")
    return 0


def _finished_rows(out: Path, checkpoint: Path, seed: int, settings: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The rows an earlier run of the same policy file, seed and settings wrote to `out`."""
    if not out.is_file():
        return {}
    try:
        saved = json.loads(out.read_text())
    except (OSError, ValueError):
        return {}  # unreadable: made again (the file is written atomically, so this is not a cut-off run)
    sha = file_sha256(checkpoint)
    return {r["row"]: r for r in saved if isinstance(r, dict) and "row" in r
            and r.get("provenance", {}).get("checkpoints", {}).get("policy", {}).get("sha256") == sha
            and r["provenance"].get("seed") == seed
            and all(r["provenance"].get("config", {}).get(k) == v for k, v in settings.items())}
