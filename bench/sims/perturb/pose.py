"""The pose axes, one row each: the episode starts from a moved arm or a moved object layout.

    init_qpos     the arm's joints offset from where the reset put them: a random direction in joint space
                  whose norm is the level (radians); with one joint named, +level on it
    object_pose   the task objects shifted on the horizontal plane by the level (metres), in a random direction
    object_yaw    the task objects turned about the vertical by the level (radians), with a random sign

A row's `start` wraps the env for the episode (`EditedStart`): its reset resets the env, then edits the
MuJoCo state (the joints' positions, the objects' free joints) through the adapter's `edit_start`, which
brings what follows from the state in line (controller goals, mocap targets, the initial state recorded)
and returns the observation of the edited state. The direction, the sign and the offset are drawn from the
episode's generator when the wrapper is made, so the record holds exactly what was applied.

Before any episode, `check_start` refuses an env without a MuJoCo state or without `edit_start`, names it
does not have, and an `init_qpos` level that could take a joint out of its range (checked from the pose of
a reset with seed 0: the small reset noise of some envs, robosuite's 0.02 rad, is not in the margin).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from bench.core.errors import ConfigError
from bench.protocols import EnvAdapter, MujocoHandle, Obs
from bench.protocols.env import AdapterWrapper
from bench.sims.perturb.axis import Axis, Named, Params
from bench.sims.perturb.model import names, resolve
from bench.sims.quaternion import quat_mul

_RUNTIME = "the env"  # `where` in errors raised while an episode starts (the names were checked before)
_BACKENDS = "robosuite, Meta-World and Gymnasium MuJoCo envs"


class EditedStart(AdapterWrapper):
    """The env whose every reset starts from the state `edit` makes of the one the reset leaves."""

    def __init__(self, env: EnvAdapter, edit: Callable[[], None]):
        super().__init__(env)
        self.edit = edit

    def reset(self, seed: int) -> Obs:
        self.inner.reset(seed)
        return self.edit_start(self.edit)  # forwarded to the adapter (`AdapterWrapper.edit_start`)


# -- targets ---------------------------------------------------------------------------------
def _handle(env: EnvAdapter, field: str, where: str) -> MujocoHandle:
    if env.mujoco is None:
        raise ConfigError(
            f"{field}: {where} ({env.backend}) has no MuJoCo state to edit; pose axes work on {_BACKENDS}"
        )
    return env.mujoco


def _joints(mj: MujocoHandle, named: Named, field: str, where: str) -> tuple[list[int], list[str]]:
    """Ids and names of the joints `init_qpos` offsets: the named ones, else the arm's (`MujocoHandle.arm_joints`)."""
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    model = mj.model
    valid = names(model, "joint", model.njnt)
    given = list(named.get("joints", mj.arm_joints))
    if not given:
        raise ConfigError(f"{field}: {where} declares no arm joints; name the joints with {field}.joints=[...]")
    ids = resolve(given, valid, "joint", f"{field}.joints", where)
    one_dof = (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE)
    for j, name in zip(ids, given):
        if model.jnt_type[j] not in one_dof:
            raise ConfigError(
                f"{field}.joints: {name!r} of {where} is a {mujoco.mjtJoint(model.jnt_type[j]).name[6:].lower()} "
                "joint; init_qpos offsets hinge and slide joints"
            )
    return ids, given


def _free_joints(mj: MujocoHandle, named: Named, field: str, where: str) -> tuple[list[int], list[str]]:
    """qpos addresses of the free joints of the objects moved: the named bodies, else the env's object bodies."""
    import mujoco  # MuJoCo's native library: loaded only when a model is simulated

    model = mj.model
    free = {
        int(model.jnt_bodyid[j]): int(model.jnt_qposadr[j])
        for j in range(model.njnt)
        if model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE
    }
    bodies = names(model, "body", model.nbody)
    placed = ", ".join(bodies[b] for b in sorted(free)) or "none"
    given = list(named.get("bodies", mj.object_bodies))
    if not given:
        raise ConfigError(
            f"{field}: {where} declares no manipulated object; name the bodies with {field}.bodies=[...] "
            f"(bodies with a free joint: {placed})"
        )
    ids = resolve(given, bodies, "body", f"{field}.bodies", where)
    for b, name in zip(ids, given):
        if b not in free:
            raise ConfigError(
                f"{field}.bodies: {name!r} of {where} has no free joint, so it has no pose of its own to move; "
                f"bodies with one: {placed}"
            )
    return [free[b] for b in ids], given


# -- checks before any episode ---------------------------------------------------------------
def _can_edit(env: EnvAdapter, field: str, where: str) -> None:
    """Reset `env` (seed 0) and start it from an unedited state: refused where the adapter cannot."""
    env.reset(0)
    try:
        EditedStart(env, lambda: None).edit_start(lambda: None)
    except NotImplementedError as exc:
        raise ConfigError(
            f"{field}: {where} ({env.backend}) cannot start an episode from an edited state ({exc}); "
            f"pose axes work on {_BACKENDS}"
        ) from None


def _check_init_qpos(env: EnvAdapter, level: float, named: Named, where: str) -> None:
    """Names, the capability, and every offset of norm `level` within the joints' ranges from the reset pose."""
    field = "perturb.init_qpos"
    mj = _handle(env, field, where)
    ids, given = _joints(mj, named, field, where)
    _can_edit(env, field, where)
    model, qpos = mj.model, mj.data.qpos
    margins = []  # (how far the joint may move, name, low, high, reset position)
    for j, name in zip(ids, given):
        if not model.jnt_limited[j]:
            continue
        low, high = (float(x) for x in model.jnt_range[j])
        q0 = float(qpos[model.jnt_qposadr[j]])
        room = high - q0 if len(ids) == 1 else min(q0 - low, high - q0)  # one joint moves by +level only
        margins.append((room, name, low, high, q0))
    if not margins or level <= min(margins)[0]:
        return
    room, name, low, high, q0 = min(margins)
    largest = max(0.0, math.floor(room * 1e4) / 1e4)
    raise ConfigError(
        f"{field}: a level of {level:g} rad can take joint {name!r} of {where} out of its range "
        f"[{low:.4g}, {high:.4g}] (it starts at {q0:.4g}); largest valid level: {largest:g}"
    )


def _check_objects(field: str) -> Callable[[EnvAdapter, float, Named, str], None]:
    def check(env: EnvAdapter, level: float, named: Named, where: str) -> None:
        _free_joints(_handle(env, field, where), named, field, where)
        _can_edit(env, field, where)

    return check


# -- starts: (env, episode generator, level, named) -> (the env to reset and step, params) -----
def _start_init_qpos(
    env: EnvAdapter, rng: np.random.Generator, level: float, named: Named
) -> tuple[EnvAdapter, Params]:
    mj = _handle(env, "perturb.init_qpos", _RUNTIME)
    ids, given = _joints(mj, named, "perturb.init_qpos", _RUNTIME)
    if len(ids) == 1:
        direction = np.ones(1)
    else:
        draw = rng.standard_normal(len(ids))
        direction = draw / np.linalg.norm(draw)
    offset = float(level) * direction
    if level == 0:
        return env, {}
    adr = mj.model.jnt_qposadr[ids]

    def edit() -> None:
        mj.data.qpos[adr] += offset

    return EditedStart(env, edit), {"init_qpos.joints": given, "init_qpos.offset": [float(x) for x in offset]}


def _start_object_pose(
    env: EnvAdapter, rng: np.random.Generator, level: float, named: Named
) -> tuple[EnvAdapter, Params]:
    mj = _handle(env, "perturb.object_pose", _RUNTIME)
    adrs, given = _free_joints(mj, named, "perturb.object_pose", _RUNTIME)
    angle = float(rng.uniform(0.0, 2.0 * math.pi))
    shift = float(level) * np.array([math.cos(angle), math.sin(angle)])
    if level == 0:
        return env, {}

    def edit() -> None:
        for a in adrs:  # the free joint's position (x, y, z): the layout moves as one, z kept
            mj.data.qpos[a : a + 2] += shift

    params: Params = {
        "object_pose.bodies": given,
        "object_pose.direction_deg": round(math.degrees(angle), 6),
        "object_pose.offset": [float(x) for x in shift],
    }
    return EditedStart(env, edit), params


def _start_object_yaw(
    env: EnvAdapter, rng: np.random.Generator, level: float, named: Named
) -> tuple[EnvAdapter, Params]:
    mj = _handle(env, "perturb.object_yaw", _RUNTIME)
    adrs, given = _free_joints(mj, named, "perturb.object_yaw", _RUNTIME)
    yaw = float(level) * (1.0 if rng.random() < 0.5 else -1.0)
    if level == 0:
        return env, {}
    turn = np.array([math.cos(yaw / 2.0), 0.0, 0.0, math.sin(yaw / 2.0)])  # about the world's z axis (w, x, y, z)

    def edit() -> None:
        qpos = mj.data.qpos
        for a in adrs:  # the free joint's orientation (w, x, y, z) after its position: turned in place
            qpos[a + 3 : a + 7] = quat_mul(turn, qpos[a + 3 : a + 7])

    return EditedStart(env, edit), {"object_yaw.bodies": given, "object_yaw.applied": yaw}


ROWS: tuple[Axis, ...] = (
    Axis(
        "init_qpos",
        "pose",
        "radians, joint-space norm",
        "initial arm joint offset",
        "the arm's joints start offset from their reset positions: a random direction in joint space (one joint "
        "named: +level on it) whose norm is the level",
        nominal=0.0,
        maximum=math.pi,
        targets=("joints",),
        start=_start_init_qpos,
        check_start=_check_init_qpos,
    ),
    Axis(
        "object_pose",
        "pose",
        "metres",
        "initial object position offset",
        "the task objects start shifted horizontally by the level, in a random direction (all by the same shift)",
        nominal=0.0,
        maximum=1.0,
        targets=("bodies",),
        start=_start_object_pose,
        check_start=_check_objects("perturb.object_pose"),
    ),
    Axis(
        "object_yaw",
        "pose",
        "radians",
        "initial object yaw",
        "the task objects start turned about the vertical by the level, with a random sign",
        nominal=0.0,
        maximum=math.pi,
        targets=("bodies",),
        start=_start_object_yaw,
        check_start=_check_objects("perturb.object_yaw"),
    ),
)
