"""`bench run ... record=DIR`: the run's rollouts as a LeRobot v3 dataset.

Workers save each finished episode's arrays next to the records (atomically, so a
record implies its trajectory); when the run ends they are assembled, in job order,
into one dataset with these features:

- `observation.state` (T, D): the suite's observation, element names from its `obs_names`
  (absent when the policy observed images only, `obs=rgb`)
- `observation.images.<camera>` (T, H, W, 3): the camera images the policy observed
  (`obs=rgb|state+rgb`), stored as LeRobot video features (MP4, H.264) beside the parquet
- `action` (T, A): what the policy commanded
- `next.reward` (T, 1), `next.success` (T, 1): per step, after the action
- `observation.sim_state` (T, nq+nv): MuJoCo qpos and qvel before the step (for replay);
  only when every episode has the same state size (one robot), since a feature has one shape
- `action.ctrl` (T, substeps x size): the MuJoCo inputs the env applied at each physics step of the
  control step, as `mj_getState(..., ctrl_spec)` gives them: actuator commands (`data.ctrl`, named
  `<actuator>@<substep>`) and, for Meta-World, the hand's mocap pose (`<body>.mocap_x@<substep>`
  ...); the mask is each episode's `ctrl_spec` metadata (same one-shape rule). `bench replay`
  re-applies them batched in `mujoco.rollout`.

and per-episode metadata (task, robot, env, split, condition, seed, sampled
parameters, success_once/at_end). The task string is the cell key, e.g. `Lift/Panda/default`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from bench.core.errors import DataError
from bench.execution.rollout import trajectory_path
from bench.logs import from_arrays, write_dataset
from bench.records import EpisodeRecord


def _expand(names: list[str]) -> list[str]:
    out = []
    for item in names:
        name, width = item.rsplit(":", 1)
        out += [name] if int(width) == 1 else [f"{name}_{i}" for i in range(int(width))]
    return out


def assemble(records: list[EpisodeRecord], trajectory_dir: Path, out: Path, robot_type: str | None = None) -> Path:
    """Write the successful-or-not (but not errored) episodes of `records` to a LeRobot v3 dataset at `out`."""
    episodes, tasks, meta = [], [], []
    obs_names = action_names = ctrl_names = None
    ctrl_specs = []
    fps = 0.0
    for r in sorted(records, key=lambda r: r.job_id):
        if r.error is not None or r.length == 0:
            continue
        path = trajectory_path(trajectory_dir, r.job_id)
        if not path.exists():
            raise DataError(f"{path}: trajectory of {r.job_id} is missing; was the run started without record=?")
        with np.load(path) as z:
            ep = {"observation.state": z["obs"]} if z["obs"].size else {}
            ep.update(
                {
                    "action": z["action"],
                    "next.reward": z["reward"].reshape(-1, 1),
                    "next.success": z["success"].reshape(-1, 1),
                }
            )
            for key in z.files:  # camera images the policy observed: rgb.<camera>
                if key.startswith("rgb."):
                    ep[f"observation.images.{key[4:]}"] = z[key]
            if z["sim_state"].size:
                ep["observation.sim_state"] = z["sim_state"]
            if "ctrl" in z.files and z["ctrl"].size:
                ep["action.ctrl"] = z["ctrl"]
                substeps = z["ctrl"].shape[1] // len(z["ctrl_names"])
                mine = [f"{a}@{k}" for k in range(substeps) for a in z["ctrl_names"]]
                ctrl_specs.append(int(z["ctrl_spec"][0]))
                if ctrl_names is None:
                    ctrl_names = mine
                elif mine != ctrl_names:  # another robot's actuators: one feature cannot name both
                    ctrl_names = []
            if "obs_names" in z.files:
                obs_names = obs_names or _expand([str(x) for x in z["obs_names"]])
            action_names = action_names or [str(x) for x in z["action_names"]]
            fps = fps or float(z["fps"][0])
        episodes.append(ep)
        spec = {"ctrl_spec": ctrl_specs[-1]} if "action.ctrl" in ep else {}
        tasks.append(f"{r.task}/{r.robot}/{r.env}")
        meta.append(
            {
                "task": r.task,
                "robot": r.robot,
                "env": r.env,
                "split": r.split,
                "condition": r.condition,
                "seed": r.seed,
                "episode": r.episode,
                "params": r.params,
                "success_once": r.success_once,
                "success_at_end": r.success_at_end,
                "policy": r.policy,
                "run_id": r.run_id,
                **spec,
            }
        )
    if not episodes:
        raise DataError("record: the run has no completed episode to record")
    assert action_names is not None, "every recorded episode set the action names"
    for feature in ("observation.sim_state", "action.ctrl"):
        widths = {ep[feature].shape[1] for ep in episodes if feature in ep}
        if len(widths) > 1 or (widths and not all(feature in ep for ep in episodes)):
            for ep in episodes:  # robots with different state sizes: one dataset cannot hold both
                ep.pop(feature, None)
    names: dict[str, list[str]] = (
        {"observation.state": obs_names, "action": action_names} if obs_names else {"action": action_names}
    )
    if ctrl_names and len(set(ctrl_specs)) == 1 and all("action.ctrl" in ep for ep in episodes):
        names["action.ctrl"] = ctrl_names
    else:  # inputs of different robots or envs: one feature cannot name both
        for ep, m in zip(episodes, meta):
            ep.pop("action.ctrl", None)
            m.pop("ctrl_spec", None)
    cameras = sorted({k for ep in episodes for k in ep if k.startswith("observation.images.")})
    ds = from_arrays(
        episodes, fps=fps or 20.0, task=tasks, meta=meta, robot_type=robot_type, names=names, video=cameras
    )
    return write_dataset(out, ds, key="record")


def episode_cell(cells: dict, episode, logs: str, suite_name: str):
    """The suite cell a recorded episode belongs to: its task string is the cell key (`Lift/Panda/default`)."""
    key = episode.tasks[0] if episode.tasks else ""
    if key not in cells:
        raise DataError(
            f"{logs}: episode {episode.index} task {key!r} is not a cell of suite {suite_name!r}; "
            f"valid: {', '.join(sorted(cells))}"
        )
    return cells[key]
