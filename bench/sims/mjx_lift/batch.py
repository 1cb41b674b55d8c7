"""N worlds of the MJX Lift scene on one arm, and each world as a bench env adapter.

`LiftBatch` holds N worlds' state in numpy between calls (qpos, qvel, orientation goal, observation, and per world
the model fields the compiled step takes: `control.WORLD_FIELDS`) and steps all of them with one compiled call
per control step; `World` is one world as a bench env adapter (`bench.protocols.EnvAdapter`), so each world is one
episode with its own record, its own seed and its own perturbation draw.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import numpy.typing as npt

from bench.core.errors import ConfigError
from bench.protocols import STATE, ActionSpec, Feature, NumArray, Obs, ObsSpec
from bench.protocols.env import CachedStateAdapter
from bench.sims.lift_obs import LIFT_OBS_FIELDS
from bench.sims.mjx_lift import control, scene

ACTION_NAMES = ("dx", "dy", "dz", "droll", "dpitch", "dyaw", "gripper")  # robosuite OSC_POSE deltas + gripper
OBS_FIELDS = LIFT_OBS_FIELDS  # the 18-number agnostic Lift observation (bench.sims.lift_obs)
AXES = frozenset({"mass", "friction", "damping", "link_mass"})  # per-world model axes (`World.apply`)
ROBOT_PREFIX = "robot0_"  # robosuite's names of the arm's joints and bodies (a calibration's draws use them)
GRIPPER_PREFIX = "gripper0_"  # robosuite's gripper bodies: this scene's hand is its own (draws of them skipped)
_FROM = {"damping": ("dof_damping",), "link_mass": ("body_mass", "body_ipos", "body_iquat", "body_inertia")}


class LiftBatch:
    """N worlds of the Lift scene on `arm`: their state in numpy, stepped together by `step_all` (one call)."""

    def __init__(self, arm: str = "Panda") -> None:
        import mujoco  # MuJoCo's native library: loaded only when a batch is made (`bench list` imports the suite)

        self.arm = arm
        self.c = control.compiled(arm)
        m = self.c.model
        data = mujoco.MjData(m)
        data.qpos[self.c.dofs] = scene.ARMS[arm].home
        data.qpos[self.c.finger_q] = scene.STROKE
        mujoco.mj_forward(m, data)
        self.home_qpos = data.qpos.copy()
        self.home_rot = data.site_xmat[self.c.grip].reshape(3, 3).copy()
        self.home_quat = data.xquat[self.c.hand].copy()
        k = self.c.cube_q
        eef = data.site_xpos[self.c.grip]
        cube = self.home_qpos[k : k + 3]
        self.home_obs = np.concatenate([eef, [0, 0, 0, 1], [1.0], cube, [0, 0, 0, 1], cube - eef]).astype(np.float32)
        self.nv = m.nv
        self.worlds: list[World] = []
        self._alloc(0)

    def _arrays(self) -> list[NumArray]:
        return [self.qpos, self.qvel, self.rgoal, self.obs, *self.fields.values()]

    def _alloc(self, n: int) -> None:
        self.qpos = np.tile(self.home_qpos, (n, 1)).astype(np.float32)
        self.qvel = np.zeros((n, self.nv), np.float32)
        self.rgoal = np.tile(self.home_rot, (n, 1, 1)).astype(np.float32)
        self.obs = np.tile(self.home_obs, (n, 1))
        self.fields = {f: np.tile(v, (n,) + (1,) * v.ndim) for f, v in self.c.nominal.items()}
        self.quat0 = np.tile(self.home_quat, (n, 1)).astype(np.float32)

    def add(self, horizon: int) -> World:
        """A world for a new env: a closed one's row again (`World.close`), else one more row in every array."""
        for world in self.worlds:
            if world.closed:
                world.closed, world.horizon = False, int(horizon)
                return world
        n = len(self.worlds) + 1
        old = self._arrays()
        self._alloc(n)
        for new, prev in zip(self._arrays(), old):
            new[: n - 1] = prev
        world = World(self, n - 1, horizon)
        self.worlds.append(world)
        return world

    def reset_world(self, i: int, seed: int) -> None:
        """World i at the home pose with its cube drawn from `seed` (robosuite Lift's placement ranges)."""
        rng = np.random.default_rng(seed)
        x, y = rng.uniform(-scene.CUBE_RANGE, scene.CUBE_RANGE, size=2)
        yaw = rng.uniform(0.0, 2.0 * np.pi)
        q = self.home_qpos.copy()
        k = self.c.cube_q
        q[k : k + 3] = (x, y, scene.TABLE_Z + scene.CUBE_HALF)
        q[k + 3 : k + 7] = (np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2))
        self.qpos[i], self.qvel[i], self.rgoal[i] = q, 0.0, self.home_rot
        obs = self.home_obs.copy()
        obs[8:11], obs[11:15] = q[k : k + 3], (0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2))  # x, y, z, w
        obs[15:18] = obs[8:11] - obs[0:3]
        self.obs[i] = obs

    def step_all(self, actions: Mapping[int, npt.ArrayLike]) -> None:
        """One control step of the worlds in `actions` (world index -> action), in one compiled call; the other
        worlds keep their state. All worlds, or one alone, are the two shapes compiled; any other subset steps
        every world and keeps the rows asked for."""
        n = len(self.worlds)
        rows = np.fromiter(actions, dtype=np.int64)
        act = np.asarray([np.asarray(a, np.float32) for a in actions.values()], np.float32)
        if act.shape != (len(rows), len(ACTION_NAMES)):
            raise ValueError(f"MJX Lift actions: shape {act.shape}; expected ({len(rows)}, {len(ACTION_NAMES)})")
        if len(rows) == 1 and n > 1:
            take = rows
        else:
            take = np.arange(n)
            full = np.zeros((n, len(ACTION_NAMES)), np.float32)
            full[rows] = act
            act = full
        if len(take) == n:  # every world: the arrays as they are (no gathered copies)
            world, state = self.fields, (self.qpos, self.qvel, self.rgoal, self.quat0)
        else:
            world = {f: v[take] for f, v in self.fields.items()}
            state = (self.qpos[take], self.qvel[take], self.rgoal[take], self.quat0[take])
        out = self.c.step(world, *state, act)
        if len(take) != len(rows):
            keep = np.isin(take, rows)
            out = [x[keep] for x in out]
        for arr, new in zip((self.qpos, self.qvel, self.rgoal, self.obs), out):
            arr[rows] = new
        for i in rows:
            self.worlds[int(i)].fresh = True

    def lifted(self) -> NumArray:
        """Per world: is its cube above the success height now (robosuite Lift's `_check_success`)."""
        return np.asarray(self.qpos[:, self.c.cube_q + 2] > scene.TABLE_Z + scene.LIFT_HEIGHT)


class World(CachedStateAdapter):
    """One world of a `LiftBatch` as a bench env adapter: one episode at a time, its own seed and axis draws.

    `step(action)` returns the world's row of the batch's last `step_all` when the vectorised runner stepped the
    batch for it (`fresh`), else steps this world alone. Model axes are per world (`model_axes` is the world):
    `mass`, `friction` scale the cube's; `damping`, `link_mass` scale the arm's joints' damping and links' mass
    and inertia; `write_draw` writes a calibration's draw (`perturb.AXIS=from(CALIBRATION)`) into this world
    alone, verbatim as the MuJoCo CPU path writes it (`bench.protocols.WritesDraws`). Derived constants (subtree
    masses, inverse weights) stay the nominal model's."""

    obs_spec: ObsSpec = {STATE: Feature.state(OBS_FIELDS)}
    action_spec = ActionSpec.box(ACTION_NAMES, -1.0, 1.0)
    fps = 1.0 / (scene.TIMESTEP * scene.SUBSTEPS)
    axes = AXES

    def __init__(self, batch: LiftBatch, index: int, horizon: int) -> None:
        import mujoco  # MuJoCo's native library: loaded by the batch already (`bench list` imports the suite)

        self.batch, self.index, self.horizon = batch, index, int(horizon)
        self.backend = f"mjx-{mujoco.__version__}/jax-{batch.c.jax.__version__}"
        self.model_axes = self
        self.fresh = False
        self.closed = False
        self._success = False

    def close(self) -> None:
        """Give the world's row back to the batch (the next `LiftBatch.add` reuses it), so an env built and closed
        to check a run's axes does not leave the batch a world larger than the run's `vector=`."""
        self.restore()
        self.closed = True

    # ModelAxes: per-world model fields
    def restore(self) -> None:
        for f, v in self.batch.c.nominal.items():
            self.batch.fields[f][self.index] = v

    def apply(self, axis: str, scale: float, targets: Mapping[str, Sequence[str]]) -> None:
        if axis not in AXES:
            raise ConfigError(f"perturb.{axis}: the MJX Lift suite varies only {sorted(AXES)} per world")
        named = [t for names in targets.values() for t in names]
        if named:
            raise ConfigError(
                f"perturb.{axis}: the MJX Lift suite perturbs the axis' default elements only (targets {named}): "
                "the cube for mass and friction, every arm joint or link for damping and link_mass"
            )
        if not np.isfinite(scale) or scale <= 0:
            raise ConfigError(f"perturb.{axis}: scale {scale} must be positive")
        c, f, i = self.batch.c, self.batch.fields, self.index
        if axis == "mass":
            f["body_mass"][i, c.cube_body] *= scale
        elif axis == "friction":
            f["geom_friction"][i, c.cube_geom, 0] *= scale
        elif axis == "damping":
            f["dof_damping"][i, c.dofs] *= scale
        else:
            links = self._links()
            f["body_mass"][i, links] *= scale
            f["body_inertia"][i, links] *= scale

    def _links(self) -> NumArray:
        """The arm's moving bodies (those of its joints)."""
        m = self.batch.c.model
        return np.array(sorted({int(m.jnt_bodyid[m.joint(j).id]) for j in scene.ARMS[self.batch.arm].joints}))

    def write_draw(self, axis: str, keys: Sequence[str], values: Sequence[float]) -> float:
        """Write one calibration draw (`field:element[:column]` keys, absolute values) into this world; returns the
        mean ratio of the drawn values to the nominal ones of the axis' first field (what perturb records).
        Elements are robosuite's names (`robot0_joint1`); robosuite's gripper bodies (`gripper0_*`) are not in
        this scene (its hand is its own) and are skipped. ConfigError naming an element the arm lacks."""
        import mujoco  # MuJoCo's native library: loaded by the batch already

        if axis not in _FROM:
            raise ConfigError(f"perturb.{axis}: from(...) on the MJX Lift suite takes {', '.join(_FROM)}")
        m, c, i = self.batch.c.model, self.batch.c, self.index
        ratios = []
        for key, value in zip(keys, values):
            field, element, *col = key.split(":")
            if field not in _FROM[axis]:
                raise ConfigError(f"perturb.{axis}: from(...) draws {field}, which the MJX Lift worlds do not carry")
            if element.startswith(GRIPPER_PREFIX):
                continue
            name = element.removeprefix(ROBOT_PREFIX)
            obj = mujoco.mjtObj.mjOBJ_JOINT if field.startswith("dof_") else mujoco.mjtObj.mjOBJ_BODY
            idx = mujoco.mj_name2id(m, obj, name)
            if idx < 0:
                raise ConfigError(
                    f"perturb.{axis}: from(...) draws {field} of {element!r}, which the MJX Lift {self.batch.arm} "
                    "does not have (a calibration of another robot?)"
                )
            row = int(m.jnt_dofadr[idx]) if field.startswith("dof_") else idx
            arr = self.batch.fields[field]
            nominal = c.nominal[field][row] if arr.ndim == 2 else c.nominal[field][row, int(col[0]) if col else 0]
            if arr.ndim == 2:
                arr[i, row] = value
            else:
                arr[i, row, int(col[0]) if col else 0] = value
            if field == _FROM[axis][0] and nominal:
                ratios.append(float(value) / float(nominal))
        return float(np.mean(ratios)) if ratios else 1.0

    def reset(self, seed: int) -> Obs:
        b, i = self.batch, self.index
        b.reset_world(i, seed)
        self.fresh = False
        self._success = False
        self._init_state = np.concatenate([b.qpos[i], b.qvel[i]]).astype(np.float64)
        return {STATE: b.obs[i].copy()}

    def step(self, action: NumArray) -> tuple[Obs, float, bool, bool, dict[str, object]]:
        b, i = self.batch, self.index
        if not self.fresh:
            b.step_all({i: action})
        self.fresh = False
        self._success = bool(b.qpos[i, b.c.cube_q + 2] > scene.TABLE_Z + scene.LIFT_HEIGHT)
        return {STATE: b.obs[i].copy()}, float(self._success), False, False, {}


def memory_estimate(worlds: int, arm: str = "Panda") -> tuple[int, int]:
    """(bytes N worlds need, bytes per world): one world's MJX data at float32 (summed over the leaves of
    `mjx.make_data` of the model put on the device) times `DATA_COPIES` (the scan's carry, the step's temporaries and
    its output), plus the per-world model fields and the batch's host arrays."""
    per = _bytes_per_world(arm)
    return int(worlds) * per, per


DATA_COPIES = 8  # live copies of one world's MJX data inside a compiled step (a bound, not a measurement)
_PER_WORLD: dict[str, int] = {}


def _bytes_per_world(arm: str) -> int:
    if arm not in _PER_WORLD:
        c = control.compiled(arm)
        leaves = c.jax.tree_util.tree_leaves(c.jax.eval_shape(c.mjx.make_data, c.mx))  # shapes only, no work
        data = sum(int(np.prod(x.shape)) * 4 for x in leaves)  # float32 / int32
        fields = sum(v.nbytes for v in c.nominal.values())
        host = 4 * (c.model.nq + c.model.nv + 9 + 4 + control.OBS_SIZE)
        _PER_WORLD[arm] = DATA_COPIES * data + 3 * fields + 3 * host
    return _PER_WORLD[arm]


def check_worlds(worlds: int, arm: str = "Panda", available: int | None = None, per: str = "") -> None:
    """Refuse, in one line, a world count whose estimated memory exceeds what the machine has free; `per` names
    how the count is made (e.g. "vector=4096 x workers=2"), for the message."""
    if available is None:
        import os  # the page count: only when a world count is checked

        available = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_AVPHYS_PAGES")
    need, one = memory_estimate(worlds, arm)
    if need > available:
        raise ConfigError(
            f"worlds={worlds}{f' ({per})' if per else ''}: the MJX Lift suite ({arm}) needs about "
            f"{need / 2**30:.1f} GiB (an estimate: {one / 1e3:.0f} kB per world from its compiled model's data) and "
            f"{available / 2**30:.1f} GiB is free; at most {available // one} worlds in all fit"
        )
