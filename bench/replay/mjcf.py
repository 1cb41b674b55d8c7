"""MJCF backend of `bench replay`: a calibration spec's model replayed as given, batched in `mujoco.rollout`."""
from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from bench.replay.common import Replay, ReplayConfig, _doc, _read_logs, summarise


def replay_mjcf(cfg: ReplayConfig) -> Replay:
    """Replay the chosen episodes in the spec's MJCF model as given, batched with `mujoco.rollout`."""
    from bench.calibrate.data import Window, extract
    from bench.calibrate.metrics import horizon_errors
    from bench.calibrate.model import Layout, Plant, load_model
    from bench.calibrate.simulate import Simulator
    from bench.calibrate.spec import load_spec

    t0 = time.perf_counter()
    spec = load_spec(Path(str(cfg.spec)).expanduser())
    model = load_model(spec.model)
    ds, eps = _read_logs(cfg)
    given = spec
    # the model as given: no declared free parameters (the Plant would clip them into their bounds), no
    # effects, and so no extra inputs (they only drive the input_channel effect)
    spec = replace(spec, params=(), effects=(), signals={k: v for k, v in spec.signals.items() if k != "inputs"})
    rec = extract(spec, [ep.data for ep in eps], float(ds.fps), nq=model.nq, nv=model.nv, nu=model.nu)
    plant = Plant(spec, model, rec)
    sim = Simulator(plant, cfg.threads)
    try:
        windows = [Window(i, 0, int(rec.offsets[i + 1] - rec.offsets[i])) for i in range(rec.n_episodes)]
        errors = horizon_errors(sim, Layout(plant).realise(np.zeros(0)), rec, windows, cfg.k)
        steps = sim.steps
    finally:
        sim.close()
    joints = [model.joint(j).name or f"q{j}" for j in range(model.njnt)]
    index = [ep.index for ep in eps]
    horizons, per_episode = summarise(errors, rec.qpos, rec.offsets, joints, index, cfg.k)
    notes = []
    if not rec.qvel_logged:
        notes.append("qvel is not logged: initial velocities are estimated from qpos (Savitzky-Golay)")
    if given.params:
        notes.append("the spec's free parameters keep the model's values (replay uses the model as given)")
    doc = _doc(cfg, "mujoco.rollout", rec.fps, index, len(rec.qpos), joints, horizons, per_episode, steps, t0, notes,
               spec=given.to_json(),  # as written; its params, effects and inputs are not used
               model=str(spec.model), substeps=int(plant.substeps), timestep=float(plant.model.opt.timestep))
    return Replay(doc, errors, rec.qpos, rec.offsets, float(rec.fps), joints, index)
