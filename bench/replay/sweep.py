"""Physical-axis sweeps of an MJCF replay: the logged episodes replayed in N perturbed worlds at once.

`bench replay spec=... logs=... perturb.damping=[0.5,2] perturb.link_mass=uniform(0.8,1.2) worlds=4`
builds one world per (condition, draw): the nominal model first, then each `perturb.*` condition (the
grammar and the model axes of `bench run`, applied by `bench.sims.perturb.reset` to a copy of the spec's
model; a range is drawn `worlds` times from a generator seeded by (seed, condition, draw)). Every
world replays every chosen episode at the three horizons; all worlds of one horizon are one batched
call, `mujoco.rollout` on the CPU (backend=mujoco) or one compiled MJX call (backend=mjx), and both
give the same records (`records`), to within `TOLERANCE` (tests/test_mjx.py holds them to it).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from types import SimpleNamespace

import mujoco
import numpy as np

from bench.core.errors import ConfigError
from bench.core.io import finite_or_none as finite
from bench.protocols import MujocoHandle
from bench.protocols.suite import Condition
from bench.replay.data import Recording
from bench.replay.metrics import horizon_segments, segment_errors
from bench.replay.simulate import Simulator, Variant, hold
from bench.sims import perturb
from bench.sims.perturb.axes import MODEL_AXES, conditions_from_config

# MJX and MuJoCo's C code agree on these records (float64, models without contact) to within this,
# relative to the logged position spread for NRMSE and in the joint's units for RMSE
TOLERANCE = 1e-6
MAX_WORLDS = 100_000


def conditions(perturb_keys: Mapping[str, object]) -> list[Condition]:
    """The sweep's conditions (nominal first); only model axes can perturb a replay."""
    conds = conditions_from_config(perturb_keys)
    for c in conds:
        if c.axis is not None and c.axis not in MODEL_AXES:
            raise ConfigError(
                f"perturb.{c.axis}: a replay sweep perturbs the model; model axes: {', '.join(MODEL_AXES)} "
                "(interface axes act on a policy's commands, which a replay takes from the log)"
            )
    return conds


def worlds(
    model: mujoco.MjModel, conds: list[Condition], draws: int, seed: int
) -> tuple[list[dict[str, object]], list[mujoco.MjModel]]:
    """One perturbed model per (condition, draw): a grid level once, a range `draws` times."""
    env = SimpleNamespace(mujoco=MujocoHandle(copy.copy(model), None), model_axes=None, backend="mjcf")
    env.mujoco.data = mujoco.MjData(env.mujoco.model)
    perturb.validate(env, conds, where="the spec's model")
    rows: list[dict[str, object]] = []
    models: list[mujoco.MjModel] = []
    for ci, cond in enumerate(conds):
        ranged = cond.kind != "grid"
        for draw in range(draws if ranged else 1):
            rng = np.random.default_rng([seed, ci, draw])
            _, params = perturb.apply(env, cond, rng)
            models.append(copy.copy(env.mujoco.model))
            rows.append({"world": len(rows), "condition": cond.name, "axis": cond.axis, "draw": draw, "params": params})
    if len(models) > MAX_WORLDS:
        raise ConfigError(
            f"worlds: {len(models)} perturbed worlds; at most {MAX_WORLDS:,} (lower worlds= or the levels)"
        )
    return rows, models


def sweep(
    sim: Simulator,
    models: list[mujoco.MjModel],
    rows: list[dict[str, object]],
    rec: Recording,
    k: int,
    joints: list[str],
) -> list[dict]:
    """Each world's replay errors per horizon (one batched call per horizon for all worlds): the records."""
    s = sim.substeps
    variants = [Variant(m, hold(rec.ctrl, s), np.zeros(m.nv)) for m in models]
    nq = rec.qpos.shape[1]
    windows = rec.episodes()
    spread = np.maximum(rec.qpos[rec.frames(windows)].std(axis=0), 1e-12)
    horizons: list[dict[str, object]] = [{} for _ in rows]
    out = [dict(r, horizons=h) for r, h in zip(rows, horizons)]
    for label, segs in horizon_segments(rec, windows, k).items():
        pred = sim.run(variants, segs)
        for w in range(len(out)):
            e = segment_errors(pred[w][..., :nq], rec, segs, spread)
            last = np.array([p[int(m.sum()) - 1] for p, m in zip(e.pred, e.mask)]) if label == "free_run" else None
            horizons[w][label] = {
                "rmse": finite(float(e.rmse.mean())),
                "nrmse": finite(float(e.nrmse.mean())),
                "per_joint_rmse": {j: finite(float(v)) for j, v in zip(joints, e.rmse)},
                **({"final_qpos": [[finite(float(v)) for v in q] for q in last]} if last is not None else {}),
            }
    return out
