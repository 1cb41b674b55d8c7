"""The MJX Lift suite against robosuite's Lift (fast path) on this machine, in one run: env-steps/s, where the
MJX step's time goes, and the scripted experts' success per arm.

    python benchmarks/bench_mjx_suite.py [worlds=[1,64,1024,4096]] [steps=10] [arms=[Panda,UR5e,Kinova3]]
        [episodes=64] [robosuite_episodes=10] [profile=256] [solvers=0]

Env-steps/s (control steps, 20 Hz, both): the MJX suite's batch (`bench.sims.mjx_lift.LiftBatch`, Panda) stepping
`worlds` worlds under the batched scripted expert (baselines/mjx_lift_expert.py), each world read through its env
adapter as the runner reads it, after a first call that compiles (printed apart), against robosuite's Lift on the
Panda through the harness's env (suites/lift.py, fast path) with its scripted expert (baselines/scripted_lift.py):
one env on one core, and one env per core in as many processes at once (what `bench run workers=<cores>` can get
from the machine), each ratio printed. Profile (`profile` worlds, Panda, 0 leaves it out): per control step, the compiled call
alone, host-side work (gathering and scattering the batch's arrays), the expert and the per-world adapter reads;
and the compiled call with 1 physics substep instead of 10 (physics vs controller + observation) and with fewer
solver iterations (variants for the record, not the suite's settings). Success: the batched expert on `episodes`
MJX worlds per arm (horizon 250) and robosuite's expert on `robosuite_episodes` episodes per arm, each with a 95%
Wilson interval. Solvers (`solvers` worlds, Panda, 0 leaves it out): the compiled call's time with other MJX solver
settings on the worlds 32 control steps into the expert's grasp (where the fingers hold the cube and the solver needs
its iterations; on the first step's states Newton stops after one everywhere), and each setting's error after one
control step against a converged solve (100 iterations, line search 50, tolerance 1e-12), from 10 states along the
grasp (steps 0, 8, ..., 72) of every world. Bad input: a world count beyond memory (estimated first) exits 2 with one line.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import sys
import time
from multiprocessing.synchronize import Barrier

import numpy as np

from baselines.mjx_lift_expert import BatchLiftExpert
from baselines.scripted_lift import LiftExpert
from bench.api.scripts import script_keys, whole
from bench.api.stats import wilson
from bench.core.errors import ConfigError
from bench.sims import mjx_lift
from bench.sims.mjx_lift import control
from suites.lift import OBS_FIELDS, make_env

HORIZON = 250
BARRIER_S = 600.0  # the robosuite processes wait this long for each other to build their envs (~10 s here)


def listed(text: str) -> list[str]:
    return [w.strip() for w in text.strip("[]").split(",") if w.strip()]


def batch_of(arm: str, worlds: int, seed: int) -> tuple[mjx_lift.LiftBatch, list[mjx_lift.World], list]:
    batch = mjx_lift.LiftBatch(arm)
    envs = [batch.add(HORIZON) for _ in range(worlds)]
    return batch, envs, [w.reset(seed + i) for i, w in enumerate(envs)]


def mjx_rate(worlds: int, steps: int) -> tuple[float, float]:
    """(env-steps/s, compile s) of `worlds` Panda worlds under the batched expert."""
    batch, envs, obs = batch_of("Panda", worlds, 0)
    expert = BatchLiftExpert(mjx_lift.OBS_FIELDS)
    began = time.perf_counter()
    for t in range(steps + 1):
        if t == 1:
            compile_s, began = time.perf_counter() - began, time.perf_counter()
        act = expert.act_batch(obs)
        batch.step_all(dict(enumerate(act)))
        obs = [w.step(a)[0] for w, a in zip(envs, act)]
    return worlds * steps / (time.perf_counter() - began), compile_s


def profile(worlds: int, steps: int) -> None:
    """Where a control step's time goes at `worlds` Panda worlds (module docstring). Every part and variant is
    timed once per round, interleaved, and the median over `steps` rounds is printed, so a loaded machine's
    swings fall on all of them alike."""
    batch, envs, obs = batch_of("Panda", worlds, 0)
    expert = BatchLiftExpert(mjx_lift.OBS_FIELDS)
    c = batch.c
    act = np.asarray(expert.act_batch(obs), np.float32)
    state = (batch.fields, batch.qpos, batch.qvel, batch.rgoal, batch.quat0, act)
    variants = {
        f"compiled call alone (as the suite: {c.substeps} substeps, solver {c.model.opt.iterations} / "
        f"line search {c.model.opt.ls_iterations}, implicitfast)": c,
        "compiled call, 1 physics substep": control.Compiled("Panda", substeps=1),
        "compiled call, solver 2 / line search 4": control.Compiled("Panda", iterations=2, ls_iterations=4),
        "compiled call, Euler integrator": control.Compiled("Panda", euler=True),
    }
    for comp in variants.values():
        comp.jax.block_until_ready(comp.step(*state))  # compile
    batch.step_all(dict(enumerate(act)))  # compiled already: the same function as "as the suite"
    times: dict[str, list[float]] = {k: [] for k in ("expert", "step_all (compiled call + host)", "adapter reads")}
    times.update({k: [] for k in variants})
    for _ in range(steps):
        t0 = time.perf_counter()
        act = expert.act_batch(obs)
        t1 = time.perf_counter()
        batch.step_all(dict(enumerate(act)))
        t2 = time.perf_counter()
        obs = [w.step(a)[0] for w, a in zip(envs, act)]
        t3 = time.perf_counter()
        for k, dt in zip(("expert", "step_all (compiled call + host)", "adapter reads"), (t1 - t0, t2 - t1, t3 - t2)):
            times[k].append(dt)
        for k, comp in variants.items():
            began = time.perf_counter()
            comp.jax.block_until_ready(comp.step(*state))
            times[k].append(time.perf_counter() - began)
    med = {k: 1e3 * float(np.median(v)) for k, v in times.items()}
    names = list(variants)
    print(f"profile, {worlds} Panda worlds, median ms per control step over {steps} interleaved rounds:")
    for k, v in med.items():
        print(f"  {k}: {v:.1f}")
    full, one = med[names[0]], med[names[1]]
    print(
        f"  -> physics ~{(full - one) / (c.substeps - 1):.1f} ms per substep ({100 * (full - one) * c.substeps / (c.substeps - 1) / full:.0f}% "
        f"of the call); controller + kinematics + observation ~{one - (full - one) / (c.substeps - 1):.1f}; "
        f"host gather/scatter ~{med['step_all (compiled call + host)'] - full:.1f}"
    )


SOLVERS: dict[str, dict[str, object]] = {  # the variants `solvers` compares (keyword arguments of control.Compiled)
    "Newton, 4 iterations / line search 8 (the suite's)": {},
    "Newton, 3 iterations": {"iterations": 3},
    "Newton, 2 iterations": {"iterations": 2},
    "Newton, 1 iteration (no while loop)": {"iterations": 1},
    "CG, 4 iterations": {"cg": True},
    "Newton, line search 4": {"ls_iterations": 4},
    "Newton, line search 2": {"ls_iterations": 2},
    "Newton, no warm start": {"warmstart": False},
}


def solvers(worlds: int, rounds: int) -> None:
    """Each solver setting's compiled-call time in the grasp and its one-step error (module docstring)."""
    batch, envs, obs = batch_of("Panda", worlds, 0)
    expert = BatchLiftExpert(mjx_lift.OBS_FIELDS)
    states = []
    for t in range(80):
        act = np.asarray(expert.act_batch(obs), np.float32)
        state = (
            {k: np.array(v) for k, v in batch.fields.items()},
            *(np.array(x) for x in (batch.qpos, batch.qvel, batch.rgoal, batch.quat0)),
            act,
        )
        if t % 8 == 0:
            states.append(state)
        batch.step_all(dict(enumerate(act)))
        obs = [w.step(a)[0] for w, a in zip(envs, act)]
    timed = states[32 // 8]  # control step 32: the fingers hold the cube
    ref = control.Compiled("Panda", iterations=100, ls_iterations=50, tolerance=1e-12)
    truth = [ref.step(*s) for s in states]
    comps = {name: control.Compiled("Panda", **kw) for name, kw in SOLVERS.items()}  # type: ignore[arg-type]
    cube = slice(ref.cube_q, ref.cube_q + 3)
    errors = {}
    for name, c in comps.items():
        out = [c.step(*s) for s in states]  # also compiles
        per = np.concatenate([np.abs(o[0][:, cube] - r[0][:, cube]).max(axis=1) for o, r in zip(out, truth)])
        errors[name] = (1e3 * float(per.max()), 1e3 * float(np.median(per)))
    times: dict[str, list[float]] = {k: [] for k in comps}
    for _ in range(rounds):
        for name, c in comps.items():
            began = time.perf_counter()
            c.jax.block_until_ready(c.step(*timed))
            times[name].append(time.perf_counter() - began)
    print(
        f"solvers, {worlds} Panda worlds: compiled call at control step 32 (median ms over {rounds} interleaved "
        "rounds); cube position error after one control step against a converged solve, over every world and 10 "
        "states (largest, median; mm):"
    )
    print("| solver | ms per call | largest error mm | median error mm |")
    print("|---|---|---|---|")
    for name in comps:
        big, mid = errors[name]
        print(f"| {name} | {1e3 * float(np.median(times[name])):.1f} | {big:.4f} | {mid:.4f} |", flush=True)


def mjx_success(arm: str, worlds: int) -> int:
    batch, envs, obs = batch_of(arm, worlds, 1000)
    expert = BatchLiftExpert(mjx_lift.OBS_FIELDS)
    lifted = np.zeros(worlds, bool)
    for _ in range(HORIZON):
        act = expert.act_batch(obs)
        batch.step_all(dict(enumerate(act)))
        obs = [w.step(a)[0] for w, a in zip(envs, act)]
        lifted |= batch.lifted()
    return int(lifted.sum())


def robosuite(arm: str, episodes: int, first: int = 1000, start: Barrier | None = None) -> tuple[float, int]:
    """(env-steps/s, successes) of robosuite's Lift on `arm` with its scripted expert, seeds `first`...; `start`:
    wait there once the env is built (the processes of `robosuite_all_cores` step at the same time)."""
    env = make_env("Lift", arm, HORIZON)
    expert = LiftExpert(OBS_FIELDS, env.action_spec.dim)
    env.reset(first)  # the first reset builds the simulation (not timed, as in every process)
    if start is not None:
        start.wait(timeout=BARRIER_S)  # a sibling that failed to start breaks it: this one fails too, not hangs
    steps, wall, wins = 0, 0.0, 0
    for ep in range(episodes):
        obs = env.reset(first + ep)
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


def _robosuite_process(arm: str, episodes: int, first: int, start: Barrier, out: mp.SimpleQueue) -> None:
    out.put(robosuite(arm, episodes, first, start)[0])


def robosuite_all_cores(arm: str, episodes: int) -> tuple[float, int]:
    """(summed env-steps/s, processes) of one robosuite env per core, stepping at once (each in its own spawned
    process, as the harness's workers: robosuite's simulation is single-threaded; as many as `bench run`'s default
    `workers`, one per core)."""
    procs = os.cpu_count() or 1
    ctx = mp.get_context("spawn")
    start, out = ctx.Barrier(procs), ctx.SimpleQueue()
    children = [
        ctx.Process(target=_robosuite_process, args=(arm, episodes, 1000 + 100 * i, start, out)) for i in range(procs)
    ]
    for c in children:
        c.start()
    for c in children:
        c.join()
    if any(c.exitcode for c in children):
        raise RuntimeError(f"a robosuite process failed (exit codes {[c.exitcode for c in children]})")
    return sum(out.get() for _ in children), procs


def interval(wins: int, n: int) -> str:
    est = wilson(wins, n)
    return f"{wins}/{n} [{est.lo:.2f}, {est.hi:.2f}]"


def main(argv: list[str]) -> int:
    a = script_keys(argv, __doc__, ("worlds", "steps", "arms", "episodes", "robosuite_episodes", "profile", "solvers"))
    try:
        worlds = [int(w) for w in listed(a.get("worlds", "[1,64,1024,4096]"))]
        arms = listed(a.get("arms", "[Panda,UR5e,Kinova3]"))
        steps, episodes = whole(a, "steps", 10), whole(a, "episodes", 64)
        rs_n, prof = whole(a, "robosuite_episodes", 10), whole(a, "profile", 256)
        solver_worlds = whole(a, "solvers", 0)
        bad = [arm for arm in arms if arm not in mjx_lift.ARMS]
        if bad:
            raise ConfigError(f"arms: {bad} not among {', '.join(mjx_lift.ARMS)}")
        for w in [*worlds, episodes, prof, solver_worlds]:
            mjx_lift.check_worlds(w)
    except (ConfigError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    load = os.getloadavg()
    print(f"machine: {os.cpu_count()} cores, load average {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} (1/5/15 min)")
    rs_rate, rs_wins = robosuite("Panda", rs_n)
    print(f"robosuite Lift (Panda, fast path, 1 env on 1 core): {rs_rate:,.0f} env-steps/s")
    all_rate, procs = robosuite_all_cores("Panda", rs_n)
    print(f"robosuite Lift (Panda, fast path, 1 env per core, {procs} processes at once): {all_rate:,.0f} env-steps/s")
    print(f"| worlds | MJX env-steps/s | compile s | MJX / robosuite on 1 core | MJX / robosuite on {procs} cores |")
    print("|---|---|---|---|---|")
    for w in worlds:
        rate, comp = mjx_rate(w, steps)
        print(f"| {w:,} | {rate:,.0f} | {comp:.1f} | {rate / rs_rate:.2f} | {rate / all_rate:.2f} |", flush=True)
    if prof:
        profile(prof, steps)
    if solver_worlds:
        solvers(solver_worlds, steps)
    print("| arm | split | MJX expert success (95% Wilson) | robosuite expert success (95% Wilson) |")
    print("|---|---|---|---|")
    for arm in arms:
        split = "seen" if arm in ("Panda", "Sawyer", "IIWA") else "unseen"
        wins = mjx_success(arm, episodes)
        rw = rs_wins if arm == "Panda" else robosuite(arm, rs_n)[1]
        print(f"| {arm} | {split} | {interval(wins, episodes)} | {interval(rw, rs_n)} |", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
