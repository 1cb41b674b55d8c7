"""`bench replay`: open-loop replay of logged commands in the simulator, per joint and per horizon.

Each logged episode is replayed from its own logged states under its logged commands, and the
simulated joint positions are compared with the logged ones at three horizons:

- `one_step`: re-initialised from the logged state every frame, one frame ahead;
- `k_step`: re-initialised every k frames, k frames ahead (truncated horizons: no drift);
- `free_run`: initialised once at the episode's first frame, to its end.

Reported per joint: RMSE (in the joint's units) and NRMSE (RMSE / std of the logged position over
the replayed frames), plus the mean over joints, per episode and over all of them.

Two backends:

- **MJCF** (`spec=`): a calibration spec (docs/calibration.md) names the model and where qpos,
  qvel and ctrl live in the log. The model is replayed *as given* (the spec's free parameters and
  effects are not used); all segments of one horizon run in one batched `mujoco.rollout` call
  (`bench.calibrate.simulate`, `bench.calibrate.metrics.horizon_errors`).
- **suite** (`suite=`): datasets written by `bench run ... record=DIR` carry the MuJoCo state
  before every step (`observation.sim_state`), the policy's action and, for robosuite and
  Meta-World envs, the MuJoCo inputs of every physics step (`action.ctrl`: actuator commands, and
  Meta-World's mocap pose). Two ways to replay them in the suite's nominal env (`commands=`):
  - `ctrl` (default when logged): the logged inputs, re-applied physics step by physics step
    from the logged states, all segments of a horizon batched in `mujoco.rollout`. This replays
    the physics alone: what the controller did is taken from the log.
  - `action`: the logged policy actions through the env's own controller (robosuite's OSC is
    Python), in a Python step loop: set the state at each segment start, `env.step` the actions.
    This also replays the controller, so a gap in what it computes shows up too.
"""
from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Optional

import numpy as np

from bench import config as config_mod
from bench.errors import ConfigError, DataError

SCHEMA = "bench.replay/1"
HORIZON_LABELS = {"one_step": "one-step", "k_step": "k-step", "free_run": "free run"}
STATIC = 1e-9  # a joint whose logged position spreads less than this has no NRMSE
COMMANDS = ("ctrl", "action")
CTRL = "action.ctrl"
ROLLOUT_BYTES = 256 * 2**20  # states returned by one mujoco.rollout call, at most


@dataclass(frozen=True)
class ReplayConfig:
    """Keys of `bench replay`."""

    logs: Optional[str] = None            # LeRobot v3 dataset folder
    spec: Optional[str] = None            # calibration spec (YAML/JSON) naming the MJCF model and log columns
    suite: Optional[str] = None           # instead of spec: suite whose env replays a `bench run record=` dataset
    k: int = 10                           # frames per k-step horizon
    episodes: Optional[list[int]] = None  # dataset episode indices (default: all)
    out: Optional[str] = None             # folder for replay.json and replay.png
    plot: int = 2                         # episodes drawn in replay.png (0: no plot)
    threads: int = 1                      # mujoco.rollout threads (results do not depend on it)
    commands: Optional[str] = None        # suite logs: ctrl (batched) | action (env step loop); default ctrl if logged


@dataclass
class Replay:
    """What a replay measured: the JSON document plus the traces behind it (for the plot)."""

    doc: dict[str, Any]
    errors: dict  # horizon -> bench.calibrate.metrics.HorizonErrors
    qpos: np.ndarray  # (N, nq) logged positions of the replayed episodes, concatenated
    offsets: np.ndarray  # (E + 1,)
    fps: float
    joints: list[str]
    episodes: list[int]  # dataset indices, in replay order


# --- shared: reading, selecting, summarising ---------------------------------------------------------
def _read_logs(cfg: ReplayConfig):
    from bench.logs import read_dataset

    path = Path(str(cfg.logs)).expanduser()
    if not path.exists():
        raise DataError(f"logs folder {str(path)!r} does not exist")
    ds = read_dataset(path)
    if not ds.episodes:
        raise DataError(f"{path}: the dataset holds no episodes")
    if cfg.episodes is None:
        return ds, list(ds.episodes)
    have = {ep.index: ep for ep in ds.episodes}
    missing = [i for i in cfg.episodes if i not in have]
    if missing:
        raise ConfigError(f"episodes={list(cfg.episodes)}: episode {missing[0]} is not in {path}; valid: "
                          f"{min(have)}..{max(have)} ({len(have)} episodes)")
    if len(set(cfg.episodes)) != len(cfg.episodes):
        raise ConfigError(f"episodes={list(cfg.episodes)}: an episode is listed twice")
    return ds, [have[i] for i in cfg.episodes]


def _check_cfg(cfg: ReplayConfig) -> None:
    if not cfg.logs:
        raise ConfigError("logs= is required (a LeRobot v3 dataset folder)")
    if cfg.spec and cfg.suite:
        raise ConfigError("give spec= (MJCF replay) or suite= (replay of a `bench run record=` dataset), not both")
    if not cfg.spec and not cfg.suite:
        raise ConfigError("spec= is required (a calibration spec naming the MJCF model and the log columns, "
                          "docs/calibration.md); for datasets written by `bench run record=`, give suite=NAME")
    if cfg.episodes is not None and not cfg.episodes:
        raise ConfigError("episodes=[] selects nothing; list dataset episode indices, e.g. episodes=[0,3], or omit it")
    if cfg.k < 1:
        raise ConfigError(f"k must be an integer >= 1 (frames per k-step horizon); got {cfg.k}")
    if cfg.plot < 0:
        raise ConfigError(f"plot must be an integer >= 0 (episodes drawn); got {cfg.plot}")
    if not 1 <= cfg.threads <= 64:
        raise ConfigError(f"threads must be an integer in [1, 64]; got {cfg.threads}")
    if cfg.commands is not None and cfg.commands not in COMMANDS:
        raise ConfigError(f"commands is {cfg.commands!r}; valid: {', '.join(COMMANDS)} (suite logs only)")
    if cfg.commands is not None and not cfg.suite:
        raise ConfigError("commands= applies to suite= replays of `bench run record=` datasets; an MJCF replay "
                          "(spec=) applies the ctrl columns the spec names")


def _num(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def _episode_of(offsets: np.ndarray, start: np.ndarray) -> np.ndarray:
    return np.searchsorted(offsets, start, side="right") - 1


def summarise(errors: dict, qpos: np.ndarray, offsets: np.ndarray, joints: list[str], episodes: list[int],
              k: int) -> tuple[dict, list[dict]]:
    """JSON-able per-horizon (per joint) and per-episode errors; NRMSE is null for joints that never move.

    Per-episode NRMSE divides by the spread over all replayed episodes, so episodes compare.
    """
    spread = qpos.std(axis=0)
    moving = spread > STATIC
    horizons: dict[str, dict] = {}
    for label, e in errors.items():
        per_joint = {}
        for j, name in enumerate(joints):
            entry = {"rmse": _num(e.rmse[j]), "nrmse": _num(e.nrmse[j]) if moving[j] else None}
            if not moving[j]:
                entry["nrmse_reason"] = "the joint does not move in the replayed logs (position std 0)"
            per_joint[name] = entry
        horizons[label] = {
            "k": 1 if label == "one_step" else k if label == "k_step" else None,
            "segments": int(len(e.start)),
            "frames": int(e.mask.sum()),
            "rmse": _num(float(e.rmse.mean())),
            "nrmse": _num(float(e.nrmse[moving].mean())) if moving.any() else None,
            "per_joint": per_joint,
        }
    per_episode = []
    for i, index in enumerate(episodes):
        row: dict[str, Any] = {"episode": int(index), "frames": int(offsets[i + 1] - offsets[i])}
        for label, e in errors.items():
            sel = _episode_of(offsets, e.start) == i
            m = e.mask[sel]
            n = max(int(m.sum()), 1)
            err = np.where(m[..., None], e.pred[sel] - e.target[sel], 0.0)
            rmse = np.sqrt((err ** 2).sum(axis=(0, 1)) / n)
            row[f"{label}_rmse"] = _num(float(rmse.mean()))
            row[f"{label}_nrmse"] = _num(float((rmse[moving] / spread[moving]).mean())) if moving.any() else None
        per_episode.append(row)
    return horizons, per_episode


# --- MJCF backend ------------------------------------------------------------------------------------
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


def _doc(cfg: ReplayConfig, backend: str, fps: float, index: list[int], frames: int, joints: list[str],
         horizons: dict, per_episode: list[dict], steps: int, t0: float, notes: list[str], **extra) -> dict:
    """The replay.json document (schema bench.replay/1): fields common to both backends, then `extra`."""
    head = {"schema": SCHEMA, "backend": backend, "logs": str(cfg.logs)}
    return {**head, **extra, "fps": float(fps), "k": int(cfg.k), "episodes": [int(i) for i in index],
            "frames": int(frames), "joints": joints, "horizons": horizons, "per_episode": per_episode,
            "sim_steps": int(steps), "wall_s": round(time.perf_counter() - t0, 4), "notes": notes}


# --- suite backend (batched logged inputs, or the env's step loop) ------------------------------------
def _coordinates(model) -> tuple[list[str], np.ndarray]:
    """Compared position coordinates: each hinge / slide joint, and the x, y, z of each free joint."""
    import mujoco

    names, idx = [], []
    for j in range(model.njnt):
        name = model.joint(j).name or f"joint{j}"
        adr, kind = int(model.jnt_qposadr[j]), int(model.jnt_type[j])
        if kind in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE):
            names.append(name)
            idx.append(adr)
        elif kind == mujoco.mjtJoint.mjJNT_FREE:
            names += [f"{name}.{a}" for a in "xyz"]
            idx += [adr, adr + 1, adr + 2]
    return names, np.array(idx, dtype=np.int64)


def _set_state(env, state: np.ndarray) -> None:
    import mujoco

    nq = env.model.nq
    env.data.qpos[:] = state[:nq]
    env.data.qvel[:] = state[nq:]
    if hasattr(env, "sim_forward"):
        env.sim_forward()
    else:
        mujoco.mj_forward(env.model, env.data)


def _suite_envs(cfg: ReplayConfig, ds, eps) -> tuple[list, list[str], np.ndarray]:
    """One nominal env per cell the episodes name; the compared coordinates (the same for all)."""
    from bench import registry
    from bench.recording import episode_cell

    suite = registry.make_suite(cfg.suite)
    cells = {c.key: c for c in suite.all_cells()}
    width = ds.feature_shape("observation.sim_state")[0]
    built: dict[str, Any] = {}
    envs = []
    names = idx = None
    try:
        for ep in eps:
            key = episode_cell(cells, ep, cfg.logs, cfg.suite).key
            if key not in built:
                env = suite.make_env(cells[key], suite.default_horizon)
                built[key] = env
                if getattr(env, "model", None) is None or getattr(env, "data", None) is None:
                    raise DataError(f"suite {cfg.suite!r}: cell {key} has no MuJoCo model/data to set states in")
                if env.model.nq + env.model.nv != width:
                    raise DataError(f"{cfg.logs}: observation.sim_state has width {width}, but cell {key}'s model "
                                    f"has nq + nv = {env.model.nq + env.model.nv}; was it recorded with this suite?")
                n, i = _coordinates(env.model)
                if names is None:
                    names, idx = n, i
                elif n != names:
                    raise DataError(f"{cfg.logs}: cells {next(iter(built))} and {key} have different joints; "
                                    f"replay one robot and task at a time (episodes=[...])")
            envs.append(built[key])
    except BaseException:
        for env in built.values():
            env.close()
        raise
    return envs, names, idx


def _back_to_back(rec, windows, k: int):
    """k-frame segments in time order with no overlap (the last one shorter, masked).

    The env carries state that the log does not (robosuite's gripper integrates its command), so a
    segment must start where the previous one ended: stepping them in order keeps that state right.
    """
    from bench.calibrate.simulate import Segments

    starts, masks = [], []
    for w in windows:
        first, last = int(rec.offsets[w.episode]) + w.start, int(rec.offsets[w.episode]) + w.stop - 1
        for s in range(first, last, k):
            starts.append(s)
            masks.append(np.arange(k) < min(k, last - s))
    return Segments(np.array(starts, dtype=np.int64), k, np.array(masks, dtype=bool).reshape(-1, k))


def _distinct(envs: list) -> list:
    """Each env once (episodes of one cell share an env), in first-use order."""
    return list({id(e): e for e in envs}.values())


def _ctrl_layout(cfg: ReplayConfig, ds, eps, envs) -> tuple[int, int]:
    """(mjtState mask, physics steps per frame) of the logged `action.ctrl`; its names must match the models."""
    import mujoco

    from bench.env import mj_input_names

    specs = {int(ep.meta.get("ctrl_spec", mujoco.mjtState.mjSTATE_CTRL)) if isinstance(ep.meta, dict)
             else int(mujoco.mjtState.mjSTATE_CTRL) for ep in eps}
    if len(specs) != 1:
        raise DataError(f"{cfg.logs}: episodes log different inputs in {CTRL!r} (ctrl_spec {sorted(specs)}); "
                        f"replay them separately (episodes=[...]) or use commands=action")
    spec = specs.pop()
    width = ds.feature_shape(CTRL)[0]
    names = ds.features[CTRL].get("names") or []
    for env in _distinct(envs):
        try:
            inputs = mj_input_names(env.model, spec)
        except ValueError as exc:
            raise DataError(f"{cfg.logs}: episode metadata 'ctrl_spec': {exc}") from None
        size = len(inputs)
        if size == 0 or width % size:
            raise DataError(f"{cfg.logs}: feature {CTRL!r} has width {width}, not a multiple of the model's {size} "
                            f"inputs ({', '.join(inputs[:4])}...); was it recorded with suite {cfg.suite!r}?")
        logged = [str(n).rsplit("@", 1)[0] for n in names[:size]]
        if names and logged != inputs:
            i = next(i for i, (a, b) in enumerate(zip(logged + [None] * size, inputs)) if a != b)
            raise DataError(f"{cfg.logs}: feature {CTRL!r} element {i} is {names[i]!r}, but input {i} of the model "
                            f"is {inputs[i]!r}; replay with commands=action or with the suite that recorded it")
    return spec, width // size


def replay_actions(envs, seeds: list, full: np.ndarray, act: np.ndarray, offsets: np.ndarray, segments: dict,
                    idx: np.ndarray) -> tuple[dict[str, np.ndarray], int]:
    """Positions after each frame of every segment, from logged actions stepped through the env in Python."""
    out, steps = {}, 0
    for label, segs in segments.items():
        pred = np.zeros((len(segs), segs.length, len(idx)))
        episode = np.searchsorted(offsets, segs.start, side="right") - 1
        current = -1
        for s, (start, e) in enumerate(zip(segs.start, episode)):
            env = envs[e]
            if e != current:  # fresh episode counters (step limits) for each episode and horizon kind
                env.reset(seeds[e] if seeds[e] is not None else 0)
                current = e
            n = segs.length if segs.mask is None else int(segs.mask[s].sum())
            _set_state(env, full[start])
            for f in range(n):
                env.step(act[start + f])
                pred[s, f] = env.data.qpos[idx]
            steps += n
        out[label] = pred
    return out, steps


def replay_ctrl(threads: int, envs, full: np.ndarray, ctrl: np.ndarray, offsets: np.ndarray, segments: dict,
                substeps: int, idx: np.ndarray, ctrl_spec: int | None = None) -> tuple[dict[str, np.ndarray], int]:
    """Positions after each frame of every segment, from logged ctrl batched in `mujoco.rollout`.

    Each segment starts from the logged qpos/qvel (the rest of the state is the env's current one)
    and applies the logged inputs of each physics step (`ctrl_spec`, an mjtState mask; default CTRL). Segments of one model
    run in one call (chunked to bound memory); `threads` rollout threads share them.
    """
    import mujoco
    from mujoco import rollout

    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    inputs = int(mujoco.mjtState.mjSTATE_CTRL) if ctrl_spec is None else int(ctrl_spec)
    by_env: dict[int, Any] = {id(e): e for e in _distinct(envs)}
    pool = rollout.Rollout(nthread=threads if threads > 1 else 0)
    datas: dict[int, list] = {k: [mujoco.MjData(e.model) for _ in range(threads)] for k, e in by_env.items()}
    out, steps = {}, 0
    try:
        for label, segs in segments.items():
            n_frames = segs.mask.sum(axis=1) if segs.mask is not None else np.full(len(segs), segs.length)
            episode = np.searchsorted(offsets, segs.start, side="right") - 1
            pred = np.zeros((len(segs), segs.length, len(idx)))
            nstep = segs.length * substeps
            for key, env in by_env.items():
                m, d = env.model, env.data
                members = np.flatnonzero([id(envs[e]) == key for e in episode])
                if not len(members):
                    continue
                size, width = mujoco.mj_stateSize(m, spec), mujoco.mj_stateSize(m, inputs)
                per = max(1, ROLLOUT_BYTES // (8 * nstep * (size + m.nsensordata)))
                for lo in range(0, len(members), per):
                    chunk = members[lo:lo + per]
                    init = np.zeros((len(chunk), size))
                    control = np.zeros((len(chunk), nstep, width))
                    for row, sgi in enumerate(chunk):
                        start, n = int(segs.start[sgi]), int(n_frames[sgi])
                        d.qpos[:] = full[start, : m.nq]
                        d.qvel[:] = full[start, m.nq:]
                        d.time = 0.0
                        mujoco.mj_getState(m, d, init[row], spec)
                        control[row, : n * substeps] = ctrl[start:start + n].reshape(n * substeps, width)
                    state, _ = pool.rollout(m, datas[key], init, control, control_spec=inputs, nstep=nstep)
                    qpos = state[:, substeps - 1::substeps, 1:1 + m.nq]  # after each frame's last physics step
                    pred[chunk] = qpos[:, :, idx]
                    steps += int(n_frames[chunk].sum()) * substeps
            out[label] = pred
    finally:
        pool.close()
    return out, steps


@dataclass
class SuiteLogs:
    """A `bench run record=` dataset made ready to replay: nominal envs plus the logged arrays, concatenated."""

    eps: list                  # dataset episodes, in replay order
    envs: list                 # the nominal env of each episode (shared by episodes of one cell)
    seeds: list                # each episode's reset seed (None if not logged)
    joints: list[str]          # compared coordinates
    idx: np.ndarray            # their qpos addresses
    full: np.ndarray           # (N, nq + nv) logged MuJoCo state before each frame
    act: np.ndarray            # (N, A) logged policy actions
    ctrl: np.ndarray | None    # (N, substeps * size) logged inputs (actuator commands, mocap poses), if recorded
    ctrl_spec: int             # their mjtState mask (0 without ctrl)
    substeps: int              # physics steps per frame (0 without ctrl)
    offsets: np.ndarray        # (E + 1,)
    rec: Any                   # bench.calibrate.data.Recording of the compared positions
    windows: list
    exact: int                 # episodes whose first state is the exact reset(seed) state

    def close(self) -> None:
        for env in _distinct(self.envs):
            env.close()


def load_suite_logs(cfg: ReplayConfig, ds, eps, need_ctrl: bool) -> SuiteLogs:
    """Build the suite's nominal envs for `eps` and gather their logs (the caller closes them).

    At each episode's start the env is reset with the episode's seed; when that state equals the
    logged one to float32 precision (the log stores float32), the exact reset state is used instead.
    """
    from bench.calibrate.data import Recording, Window

    for feat in ("observation.sim_state", "action", *((CTRL,) if need_ctrl else ())):
        if feat not in ds.features:
            hint = ("recorded by an env without a Python controller, or by robots with different actuators; "
                    "use commands=action") if feat == CTRL else \
                "suite replay needs a dataset written by `bench run ... record=DIR` with one robot (or spec=)"
            raise DataError(f"{cfg.logs}: feature {feat!r} missing; {hint}")
    lengths = [len(ep.data["action"]) for ep in eps]
    short = next((ep.index for ep, n in zip(eps, lengths) if n < 2), None)
    if short is not None:
        raise DataError(f"{cfg.logs}: episode {short} has fewer than 2 frames; nothing to replay")
    envs, joints, idx = _suite_envs(cfg, ds, eps)
    try:
        ctrl_spec, substeps = _ctrl_layout(cfg, ds, eps, envs) if need_ctrl else (0, 0)
        states = [np.asarray(ep.data["observation.sim_state"], dtype=np.float64) for ep in eps]
        seeds = [int(ep.meta["seed"]) if isinstance(ep.meta, dict) and "seed" in ep.meta else None for ep in eps]
        exact = 0
        for i, (env, seed) in enumerate(zip(envs, seeds)):
            env.reset(seed if seed is not None else 0)
            s0 = np.concatenate([env.data.qpos, env.data.qvel])
            if seed is not None and np.all(np.abs(s0 - states[i][0]) <= 1e-6 * np.maximum(1.0, np.abs(s0))):
                states[i][0] = s0  # the same state, without the float32 rounding of the log
                exact += 1
    except BaseException:
        for env in _distinct(envs):
            env.close()
        raise
    offsets = np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)
    full = np.concatenate(states)
    act = np.concatenate([np.asarray(ep.data["action"], dtype=np.float64) for ep in eps])
    ctrl = np.concatenate([np.asarray(ep.data[CTRL], dtype=np.float64) for ep in eps]) if need_ctrl else None
    rec = Recording(fps=float(ds.fps), qpos=full[:, idx], qvel=np.zeros((len(full), 0)), ctrl=act, inputs=None,
                    offsets=offsets, train=[], holdout=[], qvel_logged=True)
    windows = [Window(i, 0, n) for i, n in enumerate(lengths)]
    return SuiteLogs(eps, envs, seeds, joints, idx, full, act, ctrl, ctrl_spec, substeps, offsets, rec, windows, exact)


def suite_segments(logs: SuiteLogs, k: int, commands: str) -> dict:
    """The segments each horizon replays (the action loop steps k-step segments back to back)."""
    from bench.calibrate.metrics import horizon_segments

    segments = horizon_segments(logs.rec, logs.windows, k)
    if commands == "action":
        segments["k_step"] = _back_to_back(logs.rec, logs.windows, k)
    return segments


def replay_suite(cfg: ReplayConfig) -> Replay:
    """Replay a `bench run record=` dataset in the suite's nominal env (`commands=`: ctrl or action).

    Each segment sets the MuJoCo state from `observation.sim_state` and applies the logged
    commands; positions after each frame are compared with the next logged state.
    """
    from bench.calibrate.metrics import segment_errors

    t0 = time.perf_counter()
    ds, eps = _read_logs(cfg)
    commands = cfg.commands or ("ctrl" if CTRL in ds.features else "action")
    logs = load_suite_logs(cfg, ds, eps, need_ctrl=commands == "ctrl")
    try:
        segments = suite_segments(logs, cfg.k, commands)
        if commands == "ctrl":
            preds, steps = replay_ctrl(cfg.threads, logs.envs, logs.full, logs.ctrl, logs.offsets, segments,
                                       logs.substeps, logs.idx, logs.ctrl_spec)
        else:
            preds, steps = replay_actions(logs.envs, logs.seeds, logs.full, logs.act, logs.offsets, segments, logs.idx)
    finally:
        logs.close()
    rec, offsets, joints = logs.rec, logs.offsets, logs.joints
    spread = np.maximum(rec.qpos.std(axis=0), 1e-12)
    errors = {label: segment_errors(preds[label], rec, segs, spread) for label, segs in segments.items()}
    index = [ep.index for ep in eps]
    horizons, per_episode = summarise(errors, rec.qpos, offsets, joints, index, cfg.k)
    for row, ep in zip(per_episode, eps):
        meta = ep.meta if isinstance(ep.meta, dict) else {}
        row.update({k: meta[k] for k in ("condition", "params", "robot", "task", "env") if k in meta})
    backend = (f"{cfg.suite} ctrl, mujoco.rollout ({cfg.threads} thread{'s' if cfg.threads > 1 else ''})"
               if commands == "ctrl" else f"{cfg.suite} step loop")
    notes = [f"positions of hinge and slide joints, x/y/z of free joints; {logs.exact} of {len(eps)} episode(s) "
             f"start from the exact state of reset(seed), the rest from the logged float32 state"]
    # sim_steps: physics steps for commands=ctrl, control (env) steps for commands=action
    doc = _doc(cfg, backend, ds.fps, index, len(logs.full), joints, horizons, per_episode, steps, t0, notes,
               commands=commands, suite=cfg.suite, spec=None)
    return Replay(doc, errors, rec.qpos, offsets, float(ds.fps), joints, index)


# --- output -------------------------------------------------------------------------------------------
def render(doc: dict, console=None) -> None:
    """Per-joint RMSE / NRMSE table, one column pair per horizon."""
    from rich.console import Console
    from rich.table import Table

    console = console or Console()
    hz = doc["horizons"]
    t = Table(title=f"replay of {len(doc['episodes'])} episode(s), {doc['frames']} frames at {doc['fps']:g} Hz "
                    f"({doc['backend']}; k = {doc['k']} frames)", title_justify="left")
    t.add_column("joint", overflow="fold")
    for label in hz:
        t.add_column(f"{HORIZON_LABELS[label]} RMSE", justify="right")
        t.add_column(f"{HORIZON_LABELS[label]} NRMSE", justify="right")
    fmt = lambda v: "-" if v is None else f"{v:.3g}"  # noqa: E731
    for name in doc["joints"]:
        t.add_row(name, *[fmt(hz[h]["per_joint"][name][m]) for h in hz for m in ("rmse", "nrmse")])
    t.add_section()
    t.add_row("mean", *[fmt(hz[h][m]) for h in hz for m in ("rmse", "nrmse")], style="bold")
    console.print(t)
    for note in doc.get("notes", []):
        console.print(f"note: {note}")


def plot(rep: Replay, path: Path, n_episodes: int) -> Path | None:
    """Logged vs replayed (free run and k-step) positions per joint for the first `n_episodes` episodes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n_ep = min(n_episodes, len(rep.episodes))
    if n_ep == 0:
        return None
    nj = len(rep.joints)
    fig, axes = plt.subplots(nj, n_ep, figsize=(6.0 * n_ep, 1.9 * nj + 0.8), sharex="col", squeeze=False,
                             layout="constrained")
    free, kst = rep.errors["free_run"], rep.errors["k_step"]
    for c in range(n_ep):
        a, b = int(rep.offsets[c]), int(rep.offsets[c + 1])
        t = np.arange(b - a) / rep.fps
        fsel = np.flatnonzero(_episode_of(rep.offsets, free.start) == c)
        ksel = np.flatnonzero(_episode_of(rep.offsets, kst.start) == c)
        for j in range(nj):
            ax = axes[j, c]
            ax.plot(t, rep.qpos[a:b, j], color="black", lw=1.4, label="logged")
            for s in ksel:  # each k-step segment starts from the logged state
                f0 = int(kst.start[s]) - a
                m = kst.mask[s]
                ax.plot(t[f0:f0 + 1 + int(m.sum())], np.r_[rep.qpos[a + f0, j], kst.pred[s, m, j]],
                        color="tab:orange", lw=1.0, label="k-step" if s == ksel[0] else None)
                ax.plot(t[f0], rep.qpos[a + f0, j], ".", color="tab:orange", ms=3)
            for s in fsel:
                m = free.mask[s]
                ax.plot(t[:1 + int(m.sum())], np.r_[rep.qpos[a, j], free.pred[s, m, j]], color="tab:blue",
                        lw=1.2, ls="--", label="free run")
            if c == 0:
                ax.set_ylabel(rep.joints[j])
            if j == 0:
                ax.set_title(f"episode {rep.episodes[c]}")
        axes[-1, c].set_xlabel("time [s]")
    axes[0, 0].legend(loc="best", fontsize=8)
    fig.suptitle(f"logged vs replayed joint positions (k = {rep.doc['k']} frames)")
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def write(rep: Replay, out: Path, n_plot: int) -> Path:
    """OUT/replay.json (atomically, no NaN) and OUT/replay.png."""
    from bench.summary import write_atomic

    out.mkdir(parents=True, exist_ok=True)
    png = plot(rep, out / "replay.png", n_plot)
    rep.doc["plot"] = png.name if png else None
    path = out / "replay.json"
    write_atomic(path, rep.doc)
    return path


HELP = """usage: bench replay logs=DIR spec=SPEC [k=10] [episodes=[0,3]] [out=DIR] [plot=2] [threads=1]
       bench replay logs=DIR suite=held_out_robots [commands=ctrl|action] [k=10] [episodes=[..]] [out=DIR] [threads=1]

Open-loop replay: each logged episode is replayed from its logged states under its logged
commands, and the simulated joint positions are compared with the logged ones, per joint:
RMSE and NRMSE (RMSE / std of the logged position) at three horizons:
  one-step   re-initialised from the logged state every frame, one frame ahead
  k-step     re-initialised every k frames, k frames ahead
  free run   initialised once at the episode start, to its end
The model is replayed as given (no fitting: `bench calibrate` fits it). docs/replay.md.

keys:
  logs      LeRobot v3 dataset folder (`bench logs import` converts CSV / MAT / RLDS)
  spec      calibration spec (YAML/JSON, docs/calibration.md): the MJCF model and the log columns of
            qpos, qvel (optional) and ctrl; all segments run batched in mujoco.rollout
  suite     instead of spec, for datasets written by `bench run ... record=DIR` (they carry the
            MuJoCo state before each step): replayed in the suite's nominal env
  commands  suite logs only: ctrl = the logged inputs of every physics step (actuator commands;
            Meta-World: and the mocap pose), batched in mujoco.rollout (the physics alone; default
            when the log has action.ctrl, as robosuite and Meta-World recordings do); action = the
            logged policy actions through the env's controller in a Python step loop (physics and
            controller)
  k         frames per k-step horizon (default 10)
  episodes  dataset episode indices to replay, e.g. [0,3] (default: all)
  out       folder for replay.json (schema bench.replay/1) and replay.png (logged vs replayed)
  plot      episodes drawn in replay.png (default 2; 0 = none)
  threads   mujoco.rollout threads (default 1; results do not depend on it)

examples:
  bench calibrate generate effect=payload_mass out=/tmp/case
  bench replay logs=/tmp/case/logs spec=/tmp/case/spec.yaml k=20 out=/tmp/case/replay
  bench run robots=[Panda] episodes=2 record=/tmp/rec && bench replay logs=/tmp/rec suite=held_out_robots
"""


def run(cfg: ReplayConfig) -> Replay:
    """Validate the config and replay with the backend it names."""
    _check_cfg(cfg)
    if cfg.suite:
        return replay_suite(cfg)
    return replay_mjcf(cfg)


def main(argv: list[str]) -> int:
    """Entry point of `bench replay`."""
    if argv and argv[0] in ("-h", "--help", "help"):
        print(HELP)
        return 0
    cfg: ReplayConfig = config_mod.build_from_argv(ReplayConfig, argv, "bench replay")
    rep = run(cfg)
    render(rep.doc)
    if cfg.out:
        path = write(rep, Path(cfg.out).expanduser(), cfg.plot)
        extra = f" and {path.parent / rep.doc['plot']}" if rep.doc.get("plot") else ""
        print(f"wrote {path}{extra} ({rep.doc['wall_s']:.2f} s)", file=sys.stderr)
    return 0


