"""The 3-D world's step against the 2-D one (docs/specification.md section 11), per UAV-step at the
same B x N, compiled (``compile_step=True``) as training runs it.

Three worlds, each from one fixed state under fixed random actions (no episode ends, no resets in
the timing), alternated round by round in one process, each keeping its best round: the training
scenario (2-D, the baseline), the same scenario lifted into space with one laser ring (the 2-D
special case: what three dimensions cost by themselves) and ``train3d`` (three rings, 108 beams).
The goal is within 2x of the 2-D step. From the repository's root:

    python -m benchmarks.threed                   # B = 256, N = 5, compiled
    python -m benchmarks.threed --batch 1024 --uavs 20 --eager
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

if not __package__:  # `python benchmarks/threed.py`: the repository's root, so `benchmarks` imports
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from benchmarks.step import stepper  # noqa: E402
from benchmarks.timing import Lines, paired  # noqa: E402
from flock_torchrl import FlockingEnv  # noqa: E402

LIFTED = {"dims": 3, "climb_max": 0.0, "laser_rings": [0.0], "spawn_height": 0.0, "spawn_altitude": [10.0, 10.0],
          "goal_altitude": [10.0, 10.0]}
WORLDS = (("2-D training scenario", "train", {}), ("lifted into 3-D, one ring", "train", LIFTED),
          ("train3d, three rings", "train3d", {}))


def threed_lines(batch: int = 256, n_uavs: int = 5, rounds: int = 3, compiled: bool = True, steps: int = 10,
                 print_each: bool = True) -> list[str]:
    """The rows: microseconds per UAV-step of each of :data:`WORLDS`, and the ratio to the 2-D one."""
    envs = {name: FlockingEnv(scenario, num_envs=batch, seed=0, reading="paper_fit", policy_id="policy3_g",
                              n_uavs=n_uavs, compile_step=compiled, check_actions=False, **overrides)
            for name, scenario, overrides in WORLDS}
    best = paired({name: stepper(env, steps, "_step") for name, env in envs.items()}, rounds)
    how = "compiled" if compiled else "eager"
    base = None
    lines = Lines(print_each)
    for name, seconds in best.items():
        us = 1e6 * seconds / (steps * batch * n_uavs)
        base = base or us
        lines.say(f"3-D step ({how}), B = {batch}, N = {n_uavs}, {name:28s}: {us:8.3f} us per UAV-step "
                  f"({us / base:.2f}x the 2-D step)")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--batch", type=int, default=256)
    parser.add_argument("--uavs", type=int, default=5)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--eager", action="store_true", help="time the eager step instead of the compiled one")
    args = parser.parse_args()
    threed_lines(args.batch, args.uavs, args.rounds, compiled=not args.eager)


if __name__ == "__main__":
    main()
