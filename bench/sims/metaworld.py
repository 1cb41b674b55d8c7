"""Meta-World adapter: one Sawyer task (e.g. "drawer-open-v3") behind the `bench.protocols.env.Env` contract.

Observation: Meta-World's own flat 39-D vector (see `OBS_NAMES`): hand position,
gripper opening, up to two objects' pose, the same 18 numbers from the previous
step, and the goal position — zeroed, as in the ML benchmarks (the goal is hidden,
so a policy must infer the task from what it sees). Action: 4-D in [-1, 1]
(hand position deltas, 1 cm per unit, and gripper effort, +1 closes), clipped here.
Success is Meta-World's `info["success"]`; episodes last at most 500 steps
(Meta-World truncates there and raises on the next step).

Seeding — how initial states are pinned:
    Meta-World 3.1.1 ignores `reset(seed=...)`. An env's initial state (object and goal
    positions) is a function of one vector, `_last_rand_vec`, drawn from the env's
    `_random_reset_space` at reset; the ML benchmarks pre-draw 50 such vectors per env
    from the *global* numpy RNG and pin one with `set_task`. Here each `reset(seed)`
    calls Meta-World's own `env.seed(seed)` (which reseeds `env.np_random`) with
    `seeded_rand_vec=True` and `_freeze_rand_vec=False`, so the vector is drawn from a
    generator seeded by the episode seed alone: same seed -> same initial state,
    whatever ran before, and the global numpy RNG is never touched. The distribution is
    the benchmarks' (uniform on `_random_reset_space`) but continuous, so episode seeds
    never wrap around onto the same 50 goals. No benchmark object is built: envs are
    constructed straight from Meta-World's class table (~0.15 s each instead of 8-9 s
    for `metaworld.ML10()`).

The hidden goal stays available to privileged code through `true_goal()`: the suite's
scripted expert (`baselines/metaworld_expert.py`, Meta-World's own policy for the task)
reads the goal from the last 3 observation values, so it is given the true goal through
its input only — the observation the harness records and other policies see stays goal-free.
"""

from __future__ import annotations

import ast
import importlib.util
import warnings
from collections.abc import Callable
from importlib.metadata import version
from pathlib import Path

import numpy as np

from bench.core.errors import ConfigError, did_you_mean
from bench.protocols import STATE, TASK, ActionSpec, Feature, InputLog, MujocoHandle, Obs
from bench.protocols.env import CachedStateAdapter
from bench.sims.quaternion import quat_conj, quat_mul

MAX_PATH_LENGTH = 500  # Meta-World's truncation: one more step raises
BENCHMARKS = ("ML10", "ML25", "ML45")
ROBOT = "Sawyer"

_FRAME: list[tuple[str, int]] = [
    ("hand_pos", 3),
    ("gripper_distance", 1),  # fingers apart / 0.1 m, clipped to [0, 1]
    ("obj0_pos", 3),
    ("obj0_quat", 4),
    ("obj1_pos", 3),  # zeros when the task has one object
    ("obj1_quat", 4),
]
OBS_NAMES: list[tuple[str, int]] = _FRAME + [(f"prev_{n}", w) for n, w in _FRAME] + [("goal_pos", 3)]
ACTION_NAMES = ["dx", "dy", "dz", "grip"]
TOO_HIGH = r"Constant\(s\) may be too high"  # metaworld.policies.policy.move, on every saturated step


def quiet_metaworld() -> None:
    """Filter the warnings Meta-World would otherwise print over and over.

    The scripted policies warn "Constant(s) may be too high" whenever their P-gain
    saturates (the env clips anyway); Gymnasium's passive checker, when envs come from
    `gym.make` (not used here, filtered in case a caller does), warns about observations
    outside the space and about the hidden goal's zero-width bounds.
    """
    warnings.filterwarnings("ignore", message=TOO_HIGH, category=UserWarning)
    warnings.filterwarnings("ignore", message=r".*is not within the observation space", category=UserWarning)
    warnings.filterwarnings(
        "ignore", message=r".*Box observation space maximum and minimum values are equal", category=UserWarning
    )


def metaworld_manifest(benchmark: str) -> dict[str, dict[str, list[str]]]:
    """A Meta-World ML benchmark's split, read from Meta-World's own definition (no env is built).

    The lists are read from the installed `metaworld/env_dict.py` (`ML10_V3` etc.) by
    parsing it, which takes milliseconds; importing Meta-World instead (the fallback,
    should the file ever stop matching) costs 0.5-1 s.

    Args:
        benchmark: "ML10", "ML25" or "ML45" (case-insensitive).

    Returns:
        {"tasks": {"seen": train env names, "unseen": test env names}}, in Meta-World's
        order and unfiltered — ML25 in Meta-World 3.1.1 lists basketball-v3 on both sides.
    """
    key = str(benchmark).upper()
    if key not in BENCHMARKS:
        raise ConfigError(
            f"benchmark={benchmark!r} is not a Meta-World ML benchmark; valid: {', '.join(BENCHMARKS)}."
            f"{did_you_mean(key, list(BENCHMARKS))}"
        )
    split = _parse_env_dict(f"{key}_V3")
    if split is None:
        quiet_metaworld()
        from metaworld import env_dict  # Meta-World: loaded only when its env is made

        defined = getattr(env_dict, f"{key}_V3")
        split = {"train": list(defined["train"]), "test": list(defined["test"])}
    return {"tasks": {"seen": split["train"], "unseen": split["test"]}}


def _parse_env_dict(name: str) -> dict[str, list[str]] | None:
    """`NAME = _get_train_test_env_dict(train_env_names=[...], test_env_names=[...])` from the source, or None."""
    spec = importlib.util.find_spec("metaworld")
    if spec is None or not spec.submodule_search_locations:
        return None
    path = Path(next(iter(spec.submodule_search_locations))) / "env_dict.py"
    try:
        tree = ast.parse(path.read_text())
    except (OSError, SyntaxError):
        return None
    for node in tree.body:
        if (
            isinstance(node, ast.Assign)
            and len(node.targets) == 1
            and isinstance(node.targets[0], ast.Name)
            and node.targets[0].id == name
            and isinstance(node.value, ast.Call)
        ):
            kw = {k.arg: k.value for k in node.value.keywords}
            try:
                return {
                    "train": list(ast.literal_eval(kw["train_env_names"])),
                    "test": list(ast.literal_eval(kw["test_env_names"])),
                }
            except (KeyError, ValueError):
                return None
    return None


class MetaWorldEnv(CachedStateAdapter):
    """One Meta-World v3 task with the goal hidden; see the module docstring for seeding."""

    mujoco: MujocoHandle  # always: a MuJoCo backend

    def __init__(self, task: str, horizon: int = MAX_PATH_LENGTH, instruction: str | None = None):
        quiet_metaworld()

        import mujoco  # MuJoCo's native library: loaded only when a model is simulated
        from metaworld.env_dict import ALL_V3_ENVIRONMENTS  # Meta-World: loaded only when its env is made

        if task not in ALL_V3_ENVIRONMENTS:
            valid = list(ALL_V3_ENVIRONMENTS)
            raise ConfigError(
                f"task {task!r} is not a Meta-World v3 env; valid: {', '.join(valid)}.{did_you_mean(task, valid)}"
            )
        if not 1 <= int(horizon) <= MAX_PATH_LENGTH:
            raise ConfigError(f"horizon={horizon}: Meta-World episodes last 1..{MAX_PATH_LENGTH} steps")
        self.task, self.robot, self.horizon = task, ROBOT, int(horizon)
        env = self._env = ALL_V3_ENVIRONMENTS[task]()
        env._set_task_called = True  # the task vector is drawn at every reset instead (module doc)
        env._partially_observable = True  # goal hidden, as in the ML benchmarks
        env.__dict__.pop("sawyer_observation_space", None)  # cached property: recompute for the new observability
        self.backend = f"metaworld-{version('metaworld')}/mujoco-{mujoco.__version__}"
        self.fps = 1.0 / float(env.dt)  # control steps per second
        self.instruction = instruction  # the task as a sentence, in obs["task"] when given (the suite's data)
        spec = {STATE: Feature.state(OBS_NAMES)}
        if instruction is not None:
            spec[TASK] = Feature.text()
        self.obs_spec = spec
        self.action_spec = ActionSpec.box(ACTION_NAMES, -1.0, 1.0)
        joints = [mujoco.mj_id2name(env.model, mujoco.mjtObj.mjOBJ_JOINT, j) or "" for j in range(env.model.njnt)]
        # the Sawyer arm's joints (right_j0..right_j6), not the gripper's r_close / l_close
        self.mujoco = MujocoHandle(env.model, env.data, arm_joints=tuple(j for j in joints if j.startswith("right_j")))
        self._t = 0
        self._success = False
        self._init_state = np.zeros(0)  # set by reset
        # the inputs Meta-World drives: the gripper's two actuators and the hand's mocap body
        st = mujoco.mjtState
        self.inputs = InputLog(env.model, int(st.mjSTATE_CTRL | st.mjSTATE_MOCAP_POS | st.mjSTATE_MOCAP_QUAT))
        self._wrap_physics_steps()

    # -- inputs at every physics step (for batched replay) -------------------------------------
    def _wrap_physics_steps(self) -> None:
        """Note ctrl and the mocap pose as each `do_simulation` applies them, while the input log is active.

        Meta-World's step moves the mocap body, then `_step_mujoco_simulation(ctrl, frame_skip)`
        sets ctrl and calls `mj_step(nstep=frame_skip)`: the inputs hold for those physics steps.
        """
        import mujoco  # MuJoCo's native library: loaded only when a model is simulated

        env = self._env
        log = self.inputs
        model, data = env.model, env.data
        original = env._step_mujoco_simulation

        def stepped(ctrl, n_frames):
            if log.rows is not None:
                data.ctrl[:] = ctrl
                row = np.empty(log.size)
                mujoco.mj_getState(model, data, row, log.spec)
                log.rows.extend([row] * int(n_frames))
            return original(ctrl, n_frames)

        vars(env)["_step_mujoco_simulation"] = stepped  # this instance's method (mypy holds methods read-only)

    def reset(self, seed: int) -> Obs:
        env = self._env
        env._freeze_rand_vec = False
        env.seeded_rand_vec = True
        env.seed(int(seed))
        obs, _ = env.reset()
        self._t = 0
        self._success = False
        self._init_state = self._state_now()
        return self._observation(obs)

    def _state_now(self) -> np.ndarray:
        """init_state(): qpos, qvel, mocap position and the (hidden) goal, taken right after reset."""
        data = self.mujoco.data
        return np.concatenate([data.qpos, data.qvel, data.mocap_pos.ravel(), self.true_goal()]).copy()

    def edit_start(self, edit: Callable[[], None]) -> Obs:
        """The episode started from the state `edit` makes of the reset one (`AdapterBase.edit_start`).

        The hand is held by a weld to the mocap body, which Meta-World moves by the action: the mocap is
        carried with the hand, keeping its pose relative to the hand at reset, so the weld holds the edited
        arm where it is (Meta-World still commands the mocap's orientation back to its fixed one at every
        step). The reward's reference tcp (`init_tcp`) and the stacked previous frame are taken again, as
        Meta-World's reset takes them.
        """
        import mujoco  # MuJoCo's native library: loaded only when a model is simulated

        env, data = self._env, self.mujoco.data
        hand, mocap = data.body("hand"), int(self.mujoco.model.body("mocap").mocapid[0])
        to_hand = quat_conj(hand.xquat)
        rel_pos = _rotate(to_hand, data.mocap_pos[mocap] - hand.xpos)  # the mocap in the hand's frame
        rel_quat = quat_mul(to_hand, data.mocap_quat[mocap] / np.linalg.norm(data.mocap_quat[mocap]))
        edit()
        mujoco.mj_forward(env.model, data)
        data.mocap_pos[mocap] = hand.xpos + _rotate(hand.xquat, rel_pos)
        data.mocap_quat[mocap] = quat_mul(hand.xquat, rel_quat)
        mujoco.mj_forward(env.model, data)
        env.init_tcp = env.tcp_center
        env._prev_obs = env._get_curr_obs_combined_no_goal()  # reset's frame stack: the current frame twice
        obs = env._get_obs()
        self._init_state = self._state_now()
        return self._observation(obs)

    def step(self, action: np.ndarray) -> tuple[Obs, float, bool, bool, dict]:
        if self._t >= self.horizon:
            raise RuntimeError(f"{self.task}: episode is over after {self.horizon} steps; reset first")
        a = np.clip(np.asarray(action, dtype=np.float64), self.action_spec.low, self.action_spec.high)
        obs, reward, terminated, truncated, info = self._env.step(a)
        self._t += 1
        self._success = bool(info.get("success", 0.0))
        truncated = bool(truncated or self._t >= self.horizon)
        return self._observation(obs), float(reward), bool(terminated), truncated, dict(info)

    def _observation(self, obs: np.ndarray) -> Obs:
        """Meta-World's vector as the `state` entry, and the instruction as `task` when the env has one."""
        out: Obs = {STATE: np.asarray(obs, dtype=np.float32)}
        if self.instruction is not None:
            out[TASK] = self.instruction
        return out

    def true_goal(self) -> np.ndarray:
        """The goal position the observation hides (for privileged code such as the scripted expert)."""
        return np.array(self._env._get_pos_goal(), dtype=np.float64)

    def close(self) -> None:
        self._env.close()


def _rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Vector `v` rotated by the unit quaternion `q` (w, x, y, z)."""
    return np.asarray(quat_mul(quat_mul(q, np.array([0.0, *v])), quat_conj(q))[1:])
