"""MJCF backend of `bench replay`: a spec's model replayed as given, batched in `mujoco.rollout` or MJX.

With `perturb.*` keys, the episodes are also replayed in perturbed worlds (`bench.replay.sweep`),
all worlds of a horizon in one batched call; their records are replay.json's `sweep`.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import mujoco

from bench.replay.common import Replay, ReplayConfig, measured, read_logs
from bench.replay.data import extract
from bench.replay.metrics import horizon_errors
from bench.replay.mjx import MjxSimulator
from bench.replay.simulate import Simulator, as_given, prepare_model
from bench.replay.spec import load_model, load_signal_map
from bench.replay.sweep import conditions, sweep, worlds
from bench.sims import mjx as mjx_backend


def replay_mjcf(cfg: ReplayConfig) -> Replay:
    """Replay the chosen episodes in the spec's MJCF model as given, batched with `mujoco.rollout` (or MJX)."""
    t0 = time.perf_counter()
    given, ignored = load_signal_map(Path(str(cfg.spec)).expanduser())
    model = load_model(given.model)
    conds = conditions(cfg.perturb) if cfg.perturb else []
    if cfg.backend == "mjx":  # refused before the logs are read: no JAX, or a model MJX cannot simulate
        mjx_backend.require()
        mjx_backend.check_model(model, where=given.model.name)
    ds, eps = read_logs(cfg)
    # extra inputs only drive calibration's input_channel effect: replay neither needs nor checks them
    smap = replace(given, signals={k: v for k, v in given.signals.items() if k != "inputs"})
    rec = extract(smap, [ep.data for ep in eps], float(ds.fps), nq=model.nq, nv=model.nv, nu=model.nu)
    model, substeps = prepare_model(model, rec.fps, given.substeps)
    mujoco.mj_setConst(model, mujoco.MjData(model))
    rows, models = worlds(model, conds, cfg.worlds, cfg.seed) if conds else ([], [])
    sim = (MjxSimulator if cfg.backend == "mjx" else Simulator)(model, rec, substeps, cfg.threads)
    joints = [model.joint(j).name or f"q{j}" for j in range(model.njnt)]
    try:
        errors = horizon_errors(sim, as_given(model, rec, substeps), rec, rec.episodes(), cfg.k)
        records = sweep(sim, models, rows, rec, cfg.k, joints) if rows else None
        steps = sim.steps
    finally:
        sim.close()
    notes = []
    if not rec.qvel_logged:
        notes.append("qvel is not logged: initial velocities are estimated from qpos (Savitzky-Golay)")
    if ignored.get("params"):
        notes.append("the spec's free parameters keep the model's values (replay uses the model as given)")
    traces = Replay({}, errors, rec.qpos, rec.offsets, float(rec.fps), joints, [ep.index for ep in eps])
    extra: dict[str, Any] = {}  # `measured`'s keywords (a **dict of object could be taken for its `rows`)
    if isinstance(sim, MjxSimulator):
        extra["mjx"] = {"device": mjx_backend.device(), "compile_s": round(sim.compile_s, 3)}
    if records is not None:
        extra["sweep"] = {"worlds": len(records), "seed": cfg.seed, "draws": cfg.worlds, "records": records}
    return measured(
        cfg,
        traces,
        "mjx" if cfg.backend == "mjx" else "mujoco.rollout",
        len(rec.qpos),
        steps,
        t0,
        notes,
        spec={**given.to_json(), "ignored": sorted(ignored)},  # a calibration spec's own fields: unused
        model=str(given.model),
        substeps=int(substeps),
        timestep=float(model.opt.timestep),
        **extra,
    )
