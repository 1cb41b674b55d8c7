"""The MJX Lift suite against robosuite's Lift (fast path) on this machine, in one run: env-steps/s and success.

    python benchmarks/bench_mjx_suite.py [worlds=[1,64,1024]] [steps=20] [episodes=64] [robosuite_episodes=20]

Env-steps/s (control steps, 20 Hz, both): the MJX suite's batch (`bench.sims.mjx_lift.LiftBatch`) stepping
`worlds` worlds with the batched scripted expert (baselines/mjx_lift_expert.py), after a first call that compiles
(printed apart), against robosuite's Lift on the Panda through the harness's env (suites/lift.py, fast path) with
its scripted expert (baselines/scripted_lift.py), one env on one core. Success: the batched expert on `episodes`
MJX worlds (horizon 250) and the robosuite expert on `robosuite_episodes` episodes, each with a 95% Wilson
interval. Bad input: a world count beyond memory (estimated first) exits 2 with one line.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from baselines.mjx_lift_expert import BatchLiftExpert
from baselines.scripted_lift import LiftExpert
from bench.api.stats import wilson
from bench.core.errors import ConfigError
from bench.sims import mjx_lift
from suites.lift import OBS_FIELDS, make_env

HORIZON = 250


def args(argv: list[str]) -> dict[str, str]:
    return dict(a.split("=", 1) for a in argv)


def mjx_rate(worlds: int, steps: int) -> tuple[float, float]:
    """(env-steps/s, compile s) of `worlds` worlds under the batched expert."""
    batch = mjx_lift.LiftBatch()
    envs = [batch.add(HORIZON) for _ in range(worlds)]
    expert = BatchLiftExpert(mjx_lift.OBS_FIELDS)
    obs = [w.reset(i) for i, w in enumerate(envs)]
    began = time.perf_counter()
    for t in range(steps + 1):
        if t == 1:
            compile_s, began = time.perf_counter() - began, time.perf_counter()
        act = expert.act_batch(obs)
        batch.step_all(dict(enumerate(act)))
        obs = [w.step(a)[0] for w, a in zip(envs, act)]
    return worlds * steps / (time.perf_counter() - began), compile_s


def mjx_success(worlds: int) -> int:
    batch = mjx_lift.LiftBatch()
    envs = [batch.add(HORIZON) for _ in range(worlds)]
    expert = BatchLiftExpert(mjx_lift.OBS_FIELDS)
    obs = [w.reset(1000 + i) for i, w in enumerate(envs)]
    lifted = np.zeros(worlds, bool)
    for _ in range(HORIZON):
        act = expert.act_batch(obs)
        batch.step_all(dict(enumerate(act)))
        obs = [w.step(a)[0] for w, a in zip(envs, act)]
        lifted |= [w.success() for w in envs]
    return int(lifted.sum())


def robosuite(episodes: int) -> tuple[float, int]:
    """(env-steps/s, successes) of robosuite's Lift on the Panda with its scripted expert."""
    env = make_env("Lift", "Panda", HORIZON)
    expert = LiftExpert(OBS_FIELDS, env.action_spec.dim)
    steps, wall, wins = 0, 0.0, 0
    for ep in range(episodes):
        obs = env.reset(1000 + ep)
        expert.reset()
        won = False
        began = time.perf_counter()
        for _ in range(HORIZON):
            obs = env.step(expert.act(obs))[0]
            won = won or bool(env.success())
        wall += time.perf_counter() - began
        steps += HORIZON
        wins += won
    env.close()
    return steps / wall, wins


def main(argv: list[str]) -> int:
    a = args(argv)
    worlds = [int(w) for w in a.get("worlds", "[1,64,1024]").strip("[]").split(",")]
    steps, episodes = int(a.get("steps", 20)), int(a.get("episodes", 64))
    try:
        for w in [*worlds, episodes]:
            mjx_lift.check_worlds(w)
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    rs_rate, rs_wins = robosuite(int(a.get("robosuite_episodes", 20)))
    rs_n = int(a.get("robosuite_episodes", 20))
    print(f"robosuite Lift (Panda, fast path, 1 env): {rs_rate:,.0f} env-steps/s")
    print("| worlds | MJX env-steps/s | compile s | MJX / robosuite |")
    print("|---|---|---|---|")
    for w in worlds:
        rate, comp = mjx_rate(w, steps)
        print(f"| {w:,} | {rate:,.0f} | {comp:.1f} | {rate / rs_rate:.2f} |")
    wins = mjx_success(episodes)
    est, rs_est = wilson(wins, episodes), wilson(rs_wins, rs_n)
    lo, hi, rlo, rhi = est.lo, est.hi, rs_est.lo, rs_est.hi
    print(f"scripted expert success, MJX Lift: {wins}/{episodes} [{lo:.2f}, {hi:.2f}] (95% Wilson)")
    print(f"scripted expert success, robosuite Lift (Panda): {rs_wins}/{rs_n} [{rlo:.2f}, {rhi:.2f}] (95% Wilson)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
