"""Harness ÷ a bare ManiSkill step loop on the same task, measured in one run (CPU, no renderer).

    python benchmarks/bench_maniskill_raw.py [task=PickCube] [episodes=8] [horizon=100] [seed=0] [reset=both]

Bare loop: `gym.make("<task>-v1", obs_mode="state", control_mode="pd_joint_pos",
sim_backend="physx_cpu", render_backend="none", reward_mode=<the task's>)`, then `env.reset(seed=s)`
and `env.step(action)` in a Python loop, as a ManiSkill user writes it. Harness: the runner's
per-episode path on suite=maniskill_tasks (`bench.api.worker(plan).run(job)`: perturbation
dispatch, policy, adapter, non-finite checks, success, the record written, flushed and fsynced).
Both get the same seeds and the same action sequences (the random policy's, which depend only on
the episode seed); episodes alternate harness / bare so load drifts hit both alike, both are warmed
up first. Measured for both of the suites'
reset modes (`reset=both`, or one of them): `soft` is ManiSkill's own reset, as in the bare loop;
`rebuild` (the default) also rebuilds the PhysX scene every episode so that the same seed and
actions give the same trajectory whatever ran before, which the bare loop does not do.
Prints env-steps/s of both and their ratio (target >= 0.95).
"""

from __future__ import annotations

import sys

from bench.api.scripts import script_keys


def main(argv: list[str]) -> int:
    opts = script_keys(argv, __doc__, ("episodes", "horizon", "reset", "seed", "task"))
    modes = ("soft", "rebuild") if opts.get("reset", "both") == "both" else (opts["reset"],)
    for mode in modes:
        measure(
            opts.get("task", "PickCube"),
            int(opts.get("episodes", 8)),
            int(opts.get("horizon", 100)),
            int(opts.get("seed", 0)),
            mode,
        )
    return 0


class Bare:
    """The bare loop as a ManiSkill user writes it: `env.reset(seed=s)`, `env.step(action)`."""

    def __init__(self, env) -> None:
        self.env = env

    def reset(self, seed: int) -> None:
        self.env.reset(seed=seed)

    def step(self, action) -> None:
        self.env.step(action)

    def close(self) -> None:
        self.env.close()


def measure(task: str, episodes: int, horizon: int, seed: int, mode: str) -> None:
    import gymnasium as gym

    from bench.api.throughput import PerfConfig, harness_vs_bare, make_plan
    from bench.sims.maniskill import reward_mode
    from suites.maniskill_common import TASKS

    p = make_plan(
        PerfConfig(suite="maniskill_tasks", task=task, episodes=episodes, horizon=horizon, seed=seed),
        episodes,
        {"reset": mode},
    )
    env_id = TASKS[task].env_id

    def bare() -> Bare:
        return Bare(
            gym.make(
                env_id,
                robot_uids=p.cells[0].robot,
                obs_mode="state",
                control_mode="pd_joint_pos",
                sim_backend="physx_cpu",
                render_backend="none",
                reward_mode=reward_mode(env_id),
            )
        )

    r = harness_vs_bare(p, bare=bare)
    h, b = r["harness_steps_per_s"], r["bare_steps_per_s"]
    print(
        f"{env_id} on physx_cpu, {episodes} episodes x {p.horizon} steps, random actions (pd_joint_pos), "
        f"renderer: none, suite reset={mode}"
    )
    print(f"  harness {h:.0f} env-steps/s, bare ManiSkill loop {b:.0f} env-steps/s: harness / bare = {h / b:.3f}")


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
