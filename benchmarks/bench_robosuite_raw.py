"""Harness throughput against bare robosuite (`robosuite.make` + soft reset + `env.step`), in one run.

    python benchmarks/bench_robosuite_raw.py [robot=Panda] [episodes=8] [horizon=250] [seed=0]

The same arm, seeds and action sequences (the random policy's, which depend only on the episode
seed); episodes alternate harness / raw so that drifts in machine speed hit both alike; both time
steady state (envs built and warmed first). Harness = `bench.api.worker` running one episode
(agnostic observation, policy, perturbation wrapper, non-finite checks, record written and
fsynced); raw = robosuite alone. `bench perf` measures the same against the suite's own env
adapter, for any suite.
"""

from __future__ import annotations

import sys
import tempfile

import numpy as np

from bench.api.scripts import script_keys


class Bare:
    """Bare robosuite: the env's placement generator re-seeded per episode, its own soft reset, `env.step`."""

    def __init__(self, env) -> None:
        self.env = env

    @classmethod
    def make(cls, robot: str, horizon: int) -> Bare:
        """robosuite's own `Lift` on `robot`, made as the harness makes it (the same options), nothing else."""
        from bench.sims.robosuite import MAKE_OPTIONS, import_robosuite

        return cls(import_robosuite().make("Lift", robots=robot, horizon=horizon, **MAKE_OPTIONS))

    def reset(self, seed: int) -> None:
        self.env.rng = np.random.default_rng(seed)
        self.env.placement_initializer.rng = self.env.rng
        self.env.reset()

    def step(self, action) -> None:
        self.env.step(action)

    def close(self) -> None:
        self.env.close()


def plan(robot: str, episodes: int, horizon: int, seed: int = 0, run_id: str = "raw-bench", fast: bool = True):
    """held_out_robots with the random policy on one arm: the plan both this script and bench_throughput time."""
    from bench import api

    return api.plan(
        api.RunConfig(
            suite="held_out_robots",
            policy="random",
            robots=[robot],
            episodes=episodes,
            seed=seed,
            horizon=horizon,
            out=tempfile.gettempdir(),
            run_id=run_id,
            suite_options={"fast_path": fast},
        )
    )


def main(argv: list[str]) -> int:
    from bench.api.throughput import harness_vs_bare

    kv = script_keys(argv, __doc__, ("episodes", "horizon", "robot", "seed"))
    robot, episodes = kv.get("robot", "Panda"), int(kv.get("episodes", 8))
    horizon, seed = int(kv.get("horizon", 250)), int(kv.get("seed", 0))
    p = plan(robot, episodes, horizon, seed)

    res = harness_vs_bare(p, bare=lambda: Bare.make(robot, horizon))
    h, r = res["harness_steps_per_s"], res["bare_steps_per_s"]
    print(f"robosuite Lift/{robot}, {episodes} episodes x {horizon} steps, random policy")
    print(f"harness {h:.1f} env-steps/s, raw robosuite {r:.1f} env-steps/s: harness / raw = {h / r:.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
