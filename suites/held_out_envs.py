"""held_out_envs: Meta-World ML10 / ML45 — transfer to whole manipulation tasks the policy never saw.

Two registered suites, one per Meta-World benchmark (a task that is held out in
ML10 is a training task in ML45, so one suite holding both would not have a clean
split):
    held_out_envs       ML10: 10 training tasks seen, 5 test tasks unseen.
    held_out_envs_ml45  ML45: 45 training tasks seen, 5 test tasks unseen.
Select a subset with `tasks=[drawer-open-v3,...]` or `splits=[unseen]`.

Task:
    Meta-World v3 (3.1.1) single-task envs on the Sawyer arm, e.g. "drawer-open-v3".
    Each episode draws the object and goal positions from the task's own reset
    distribution, pinned by the episode seed (see `bench.sims.metaworld`).
Split (Meta-World's own definitions; `bench.sims.metaworld.metaworld_manifest` reads them):
    ML10  seen   = reach, push, pick-place, door-open, drawer-close,
                   button-press-topdown, peg-insert-side, window-open, sweep, basketball
          unseen = drawer-open, door-close, shelf-place, sweep-into, lever-pull
    ML45  seen   = the other 45 v3 tasks
          unseen = bin-picking, box-close, hand-insert, door-lock, door-unlock
    Cells: task = env name, robot = "Sawyer", env = "ML10" / "ML45".
Observation:
    Meta-World's 39-D vector with the goal hidden (last 3 values zeroed), as in the
    ML benchmarks: the policy must infer the task from the scene; and `task`, the task
    as an instruction ("open the drawer"; `instructions/metaworld.json`), which policies
    that read only `state` never see.
Action:
    4-D in [-1, 1]: hand position deltas (x, y, z) and gripper effort (+1 closes).
Cameras (`obs=rgb|state+rgb`, `cameras=`, `image_size=`):
    default rgb.corner (front corner view) and rgb.gripperPOV (in the gripper); others:
    topview, corner2, corner3, corner4, behindGripper.
Conditions:
    nominal; perturbations via `perturb.*` act on the MuJoCo model; visual axes on the images.
Success:
    Meta-World's `info["success"]`: success_once = at any step, success_at_end = at
    the last step; 500 steps (Meta-World's limit; `horizon=` may only shorten it).
Metric:
    success rate per task with Wilson intervals; mean over seen (train) and unseen
    (test) tasks with a stratified bootstrap interval; transfer gap = seen - unseen.
Reference policy:
    `scripted` = Meta-World's own scripted policy per task, given the true goal
    through its input only. `metaworld_language` = the same experts, chosen by the
    words of the instruction (for `perturb.instruction`, docs/perturbations.md).
"""

from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import Any

from bench.api.sims import CameraOptions, camera_spec, check_options, unwrap
from bench.protocols import STATE, TASK, Feature, ObsSpec
from bench.protocols.suite import Cell, SuiteBase

MAX_PATH_LENGTH = 500  # = bench.sims.metaworld.MAX_PATH_LENGTH (not imported: keeps `bench list` free of Meta-World)
# Meta-World 3.1.1's cameras (its Sawyer XML, the same on every task); defaults: a front corner view and the
# camera in the gripper
CAMERAS = ("topview", "corner", "corner2", "corner3", "corner4", "behindGripper", "gripperPOV")
DEFAULT_CAMERAS = ("corner", "gripperPOV")
# every v3 task as an instruction, with its paraphrases (`perturb.instruction`; package data)
INSTRUCTIONS = Path(__file__).with_name("instructions") / "metaworld.json"


@functools.cache
def instruction(task: str) -> str:
    """The task as an instruction sentence ("drawer-open-v3" -> "open the drawer"), from `INSTRUCTIONS`."""
    return str(json.loads(INSTRUCTIONS.read_text(encoding="utf-8"))["tasks"][task]["instruction"])


# Meta-World 3.1.1's ML10_V3 / ML45_V3 (metaworld/env_dict.py), kept here so that listing the
# suite does not import Meta-World; tests/test_held_out_envs.py checks them against the source.
ML10 = {
    "seen": [
        "reach-v3",
        "push-v3",
        "pick-place-v3",
        "door-open-v3",
        "drawer-close-v3",
        "button-press-topdown-v3",
        "peg-insert-side-v3",
        "window-open-v3",
        "sweep-v3",
        "basketball-v3",
    ],
    "unseen": ["drawer-open-v3", "door-close-v3", "shelf-place-v3", "sweep-into-v3", "lever-pull-v3"],
}
ML45 = {
    "seen": [
        "assembly-v3",
        "basketball-v3",
        "button-press-topdown-v3",
        "button-press-topdown-wall-v3",
        "button-press-v3",
        "button-press-wall-v3",
        "coffee-button-v3",
        "coffee-pull-v3",
        "coffee-push-v3",
        "dial-turn-v3",
        "disassemble-v3",
        "door-close-v3",
        "door-open-v3",
        "drawer-close-v3",
        "drawer-open-v3",
        "faucet-open-v3",
        "faucet-close-v3",
        "hammer-v3",
        "handle-press-side-v3",
        "handle-press-v3",
        "handle-pull-side-v3",
        "handle-pull-v3",
        "lever-pull-v3",
        "pick-place-wall-v3",
        "pick-out-of-hole-v3",
        "push-back-v3",
        "pick-place-v3",
        "plate-slide-v3",
        "plate-slide-side-v3",
        "plate-slide-back-v3",
        "plate-slide-back-side-v3",
        "peg-insert-side-v3",
        "peg-unplug-side-v3",
        "soccer-v3",
        "stick-push-v3",
        "stick-pull-v3",
        "push-wall-v3",
        "push-v3",
        "reach-wall-v3",
        "reach-v3",
        "shelf-place-v3",
        "sweep-into-v3",
        "sweep-v3",
        "window-open-v3",
        "window-close-v3",
    ],
    "unseen": ["bin-picking-v3", "box-close-v3", "hand-insert-v3", "door-lock-v3", "door-unlock-v3"],
}


class _MetaWorldSplit(SuiteBase):
    """Shared body of the Meta-World suites; subclasses set `benchmark` and `manifest`."""

    benchmark: str = ""
    version = "1"
    Options = CameraOptions
    reference_policy = "scripted"
    default_horizon = MAX_PATH_LENGTH
    max_horizon = MAX_PATH_LENGTH  # Meta-World raises on step 501
    capabilities = frozenset({"expert"})
    instructions = str(INSTRUCTIONS)

    def __init__(self, options: Any = None) -> None:
        super().__init__(options)
        check_options(self.options, CAMERAS, "Meta-World")

    def all_cells(self) -> list[Cell]:
        split = self.manifest["tasks"]
        return [Cell(self.name, t, "Sawyer", self.benchmark, side) for side in ("seen", "unseen") for t in split[side]]

    def obs_spec(self, cell: Cell) -> ObsSpec:
        from bench.api.sims import OBS_NAMES

        return camera_spec({STATE: Feature.state(OBS_NAMES), TASK: Feature.text()}, self.options, DEFAULT_CAMERAS)

    def make_env(self, cell: Cell, horizon: int):
        from bench.api.sims import MetaWorldEnv, with_cameras

        env = MetaWorldEnv(cell.task, min(int(horizon), MAX_PATH_LENGTH), instruction(cell.task))
        return with_cameras(env, self.options, DEFAULT_CAMERAS, cell.key)

    def make_expert(self, cell: Cell, env):
        from baselines.metaworld_expert import make_expert

        return make_expert(unwrap(env))


class HeldOutEnvs(_MetaWorldSplit):
    """Meta-World ML10: 10 training tasks seen, 5 test tasks held out (Sawyer, goal hidden)."""

    name = "held_out_envs"
    benchmark = "ML10"
    manifest = {"tasks": ML10}


class HeldOutEnvsML45(_MetaWorldSplit):
    """Meta-World ML45: 45 training tasks seen, 5 test tasks held out (Sawyer, goal hidden)."""

    name = "held_out_envs_ml45"
    benchmark = "ML45"
    manifest = {"tasks": ML45}
