"""Suite backend of `bench replay`: `bench run record=` datasets replayed in the suite's nominal env.

Logged inputs batched in `mujoco.rollout` (`commands=ctrl`) or logged actions through the env's step loop
(`commands=action`); see the package docstring.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from bench.core.errors import DataError
from bench.execution.recording import episode_cell
from bench.protocols import EnvAdapter, MujocoHandle, registry
from bench.protocols.env import mj_input_names
from bench.replay.common import CTRL, ROLLOUT_BYTES, Replay, ReplayConfig, measured, read_logs
from bench.replay.data import Recording, Window
from bench.replay.metrics import horizon_segments, segment_errors
from bench.replay.simulate import Segments


def _coordinates(model) -> tuple[list[str], np.ndarray]:
    """Compared position coordinates: each hinge / slide joint, and the x, y, z of each free joint."""
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

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


def _set_state(env: EnvAdapter, state: np.ndarray) -> None:

    mj = env.mujoco
    if mj is None:
        raise DataError(f"replay: env {env.backend} has no MuJoCo state to set")
    nq = mj.model.nq
    mj.data.qpos[:] = state[:nq]
    mj.data.qvel[:] = state[nq:]
    mj.forward()


def _suite_envs(cfg: ReplayConfig, ds, eps) -> tuple[list, list[str], np.ndarray]:
    """One nominal env per cell the episodes name; the compared coordinates (the same for all)."""
    assert cfg.suite is not None and cfg.logs is not None, "a suite replay names its suite and logs (check_config)"
    suite = registry.make_suite(cfg.suite)
    cells = {c.key: c for c in suite.all_cells()}
    width = ds.feature_shape("observation.sim_state")[0]
    built: dict[str, EnvAdapter] = {}
    envs = []
    names: list[str] | None = None
    idx: np.ndarray | None = None
    try:
        for ep in eps:
            key = episode_cell(cells, ep, cfg.logs, cfg.suite).key
            if key not in built:
                env = suite.make_env(cells[key], suite.default_horizon)
                built[key] = env
                if env.mujoco is None:
                    raise DataError(f"suite {cfg.suite!r}: cell {key} has no MuJoCo model/data to set states in")
                if env.mujoco.model.nq + env.mujoco.model.nv != width:
                    raise DataError(
                        f"{cfg.logs}: observation.sim_state has width {width}, but cell {key}'s model "
                        f"has nq + nv = {env.mujoco.model.nq + env.mujoco.model.nv}; was it recorded with this suite?"
                    )
                n, i = _coordinates(env.mujoco.model)
                if names is None:
                    names, idx = n, i
                elif n != names:
                    raise DataError(
                        f"{cfg.logs}: cells {next(iter(built))} and {key} have different joints; "
                        f"replay one robot and task at a time (episodes=[...])"
                    )
            envs.append(built[key])
    except BaseException:
        for env in built.values():
            env.close()
        raise
    assert names is not None and idx is not None, "the dataset holds at least one episode (read_logs)"
    return envs, names, idx


def _back_to_back(rec, windows, k: int):
    """k-frame segments in time order with no overlap (the last one shorter, masked).

    The env carries state that the log does not (robosuite's gripper integrates its command), so a
    segment must start where the previous one ended: stepping them in order keeps that state right.
    """
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
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    specs = {
        int(ep.meta.get("ctrl_spec", mujoco.mjtState.mjSTATE_CTRL))
        if isinstance(ep.meta, dict)
        else int(mujoco.mjtState.mjSTATE_CTRL)
        for ep in eps
    }
    if len(specs) != 1:
        raise DataError(
            f"{cfg.logs}: episodes log different inputs in {CTRL!r} (ctrl_spec {sorted(specs)}); "
            f"replay them separately (episodes=[...]) or use commands=action"
        )
    spec = specs.pop()
    width = ds.feature_shape(CTRL)[0]
    names = ds.features[CTRL].get("names") or []
    for env in _distinct(envs):
        try:
            inputs = mj_input_names(env.mujoco.model, spec)
        except ValueError as exc:
            raise DataError(f"{cfg.logs}: episode metadata 'ctrl_spec': {exc}") from None
        size = len(inputs)
        if size == 0 or width % size:
            raise DataError(
                f"{cfg.logs}: feature {CTRL!r} has width {width}, not a multiple of the model's {size} "
                f"inputs ({', '.join(inputs[:4])}...); was it recorded with suite {cfg.suite!r}?"
            )
        logged = [str(n).rsplit("@", 1)[0] for n in names[:size]]
        if names and logged != inputs:
            i = next(i for i, (a, b) in enumerate(zip(logged + [None] * size, inputs)) if a != b)
            raise DataError(
                f"{cfg.logs}: feature {CTRL!r} element {i} is {names[i]!r}, but input {i} of the model "
                f"is {inputs[i]!r}; replay with commands=action or with the suite that recorded it"
            )
    return spec, width // size


def replay_actions(
    envs, seeds: list, full: np.ndarray, act: np.ndarray, offsets: np.ndarray, segments: dict, idx: np.ndarray
) -> tuple[dict[str, np.ndarray], int]:
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
                pred[s, f] = env.mujoco.data.qpos[idx]
            steps += n
        out[label] = pred
    return out, steps


def replay_ctrl(
    threads: int,
    envs,
    full: np.ndarray,
    ctrl: np.ndarray,
    offsets: np.ndarray,
    segments: dict,
    substeps: int,
    idx: np.ndarray,
    ctrl_spec: int | None = None,
) -> tuple[dict[str, np.ndarray], int]:
    """Positions after each frame of every segment, from logged ctrl batched in `mujoco.rollout`.

    Each segment starts from the logged qpos/qvel (the rest of the state is the env's current one)
    and applies the logged inputs of each physics step (`ctrl_spec`, an mjtState mask; default CTRL). Segments of one model
    run in one call (chunked to bound memory); `threads` rollout threads share them.
    """
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated
    from mujoco import rollout  # MuJoCo's native library: loaded only when a model is simulated

    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    inputs = int(mujoco.mjtState.mjSTATE_CTRL) if ctrl_spec is None else int(ctrl_spec)
    by_env: dict[int, MujocoHandle] = {id(e): e.mujoco for e in _distinct(envs)}  # each env's, by the env's id
    pool = rollout.Rollout(nthread=threads if threads > 1 else 0)
    datas: dict[int, list] = {k: [mujoco.MjData(mj.model) for _ in range(threads)] for k, mj in by_env.items()}
    out, steps = {}, 0
    try:
        for label, segs in segments.items():
            n_frames = segs.mask.sum(axis=1) if segs.mask is not None else np.full(len(segs), segs.length)
            episode = np.searchsorted(offsets, segs.start, side="right") - 1
            pred = np.zeros((len(segs), segs.length, len(idx)))
            nstep = segs.length * substeps
            for key, mj in by_env.items():
                m, d = mj.model, mj.data
                members = np.flatnonzero([id(envs[e]) == key for e in episode])
                if not len(members):
                    continue
                size, width = mujoco.mj_stateSize(m, spec), mujoco.mj_stateSize(m, inputs)
                per = max(1, ROLLOUT_BYTES // (8 * nstep * (size + m.nsensordata)))
                for lo in range(0, len(members), per):
                    chunk = members[lo : lo + per]
                    init = np.zeros((len(chunk), size))
                    control = np.zeros((len(chunk), nstep, width))
                    for row, sgi in enumerate(chunk):
                        start, n = int(segs.start[sgi]), int(n_frames[sgi])
                        d.qpos[:] = full[start, : m.nq]
                        d.qvel[:] = full[start, m.nq :]
                        d.time = 0.0
                        mujoco.mj_getState(m, d, init[row], spec)
                        control[row, : n * substeps] = ctrl[start : start + n].reshape(n * substeps, width)
                    state, _ = pool.rollout(m, datas[key], init, control, control_spec=inputs, nstep=nstep)
                    qpos = state[:, substeps - 1 :: substeps, 1 : 1 + m.nq]  # after each frame's last physics step
                    pred[chunk] = qpos[:, :, idx]
                    steps += int(n_frames[chunk].sum()) * substeps
            out[label] = pred
    finally:
        pool.close()
    return out, steps


@dataclass
class SuiteLogs:
    """A `bench run record=` dataset made ready to replay: nominal envs plus the logged arrays, concatenated."""

    eps: list  # dataset episodes, in replay order
    envs: list  # the nominal env of each episode (shared by episodes of one cell)
    seeds: list  # each episode's reset seed (None if not logged)
    joints: list[str]  # compared coordinates
    idx: np.ndarray  # their qpos addresses
    full: np.ndarray  # (N, nq + nv) logged MuJoCo state before each frame
    act: np.ndarray  # (N, A) logged policy actions
    ctrl: np.ndarray | None  # (N, substeps * size) logged inputs (actuator commands, mocap poses), if recorded
    ctrl_spec: int  # their mjtState mask (0 without ctrl)
    substeps: int  # physics steps per frame (0 without ctrl)
    offsets: np.ndarray  # (E + 1,)
    rec: Recording  # the compared positions
    windows: list
    exact: int  # episodes whose first state is the exact reset(seed) state

    def close(self) -> None:
        for env in _distinct(self.envs):
            env.close()


def load_suite_logs(cfg: ReplayConfig, ds, eps, need_ctrl: bool) -> SuiteLogs:
    """Build the suite's nominal envs for `eps` and gather their logs (the caller closes them).

    At each episode's start the env is reset with the episode's seed; when that state equals the
    logged one to float32 precision (the log stores float32), the exact reset state is used instead.
    """
    for feat in ("observation.sim_state", "action", *((CTRL,) if need_ctrl else ())):
        if feat not in ds.features:
            hint = (
                (
                    "recorded by an env without a Python controller, or by robots with different actuators; "
                    "use commands=action"
                )
                if feat == CTRL
                else "suite replay needs a dataset written by `bench run ... record=DIR` with one robot (or spec=)"
            )
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
            s0 = np.concatenate([env.mujoco.data.qpos, env.mujoco.data.qvel])
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
    rec = Recording(
        fps=float(ds.fps),
        qpos=full[:, idx],
        qvel=np.zeros((len(full), 0)),
        ctrl=act,
        inputs=None,
        offsets=offsets,
        train=[],
        holdout=[],
        qvel_logged=True,
    )
    windows = [Window(i, 0, n) for i, n in enumerate(lengths)]
    return SuiteLogs(eps, envs, seeds, joints, idx, full, act, ctrl, ctrl_spec, substeps, offsets, rec, windows, exact)


def suite_segments(logs: SuiteLogs, k: int, commands: str) -> dict:
    """The segments each horizon replays (the action loop steps k-step segments back to back)."""
    segments = horizon_segments(logs.rec, logs.windows, k)
    if commands == "action":
        segments["k_step"] = _back_to_back(logs.rec, logs.windows, k)
    return segments


def replay_suite(cfg: ReplayConfig) -> Replay:
    """Replay a `bench run record=` dataset in the suite's nominal env (`commands=`: ctrl or action).

    Each segment sets the MuJoCo state from `observation.sim_state` and applies the logged
    commands; positions after each frame are compared with the next logged state.
    """
    t0 = time.perf_counter()
    ds, eps = read_logs(cfg)
    commands = cfg.commands or ("ctrl" if CTRL in ds.features else "action")
    logs = load_suite_logs(cfg, ds, eps, need_ctrl=commands == "ctrl")
    try:
        segments = suite_segments(logs, cfg.k, commands)
        if commands == "ctrl":
            assert logs.ctrl is not None, "load_suite_logs(need_ctrl=True) loads the logged inputs"
            preds, steps = replay_ctrl(
                cfg.threads,
                logs.envs,
                logs.full,
                logs.ctrl,
                logs.offsets,
                segments,
                logs.substeps,
                logs.idx,
                logs.ctrl_spec,
            )
        else:
            preds, steps = replay_actions(logs.envs, logs.seeds, logs.full, logs.act, logs.offsets, segments, logs.idx)
    finally:
        logs.close()
    rec, offsets, joints = logs.rec, logs.offsets, logs.joints
    spread = np.maximum(rec.qpos.std(axis=0), 1e-12)
    errors = {label: segment_errors(preds[label], rec, segs, spread) for label, segs in segments.items()}
    metas = [ep.meta if isinstance(ep.meta, dict) else {} for ep in eps]
    rows = [{k: meta[k] for k in ("condition", "params", "robot", "task", "env") if k in meta} for meta in metas]
    backend = (
        f"{cfg.suite} ctrl, mujoco.rollout ({cfg.threads} thread{'s' if cfg.threads > 1 else ''})"
        if commands == "ctrl"
        else f"{cfg.suite} step loop"
    )
    notes = [
        f"positions of hinge and slide joints, x/y/z of free joints; {logs.exact} of {len(eps)} episode(s) "
        f"start from the exact state of reset(seed), the rest from the logged float32 state"
    ]
    traces = Replay({}, errors, rec.qpos, offsets, float(ds.fps), joints, [ep.index for ep in eps])
    # sim_steps: physics steps for commands=ctrl, control (env) steps for commands=action
    return measured(
        cfg, traces, backend, len(logs.full), steps, t0, notes, rows, commands=commands, suite=cfg.suite, spec=None
    )
