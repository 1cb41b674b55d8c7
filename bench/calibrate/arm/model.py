"""The declared model of a real arm: a suite's own robot in its scene, or an MJCF; its joints, links and flange.

`build` resolves what an arm spec names in the model (joints by name or unique suffix, the links
they move, the payload frame, the motors that drive them) and `check_log` refuses logs that cannot
be this arm's before anything is fitted: another joint count, degrees for radians, mN·m for N·m,
joints in another order. `realise` writes a fit's values back into a copy of the model, which is
what runs carry (`bench.calibrate.apply`) and the forward-simulation check steps.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from typing import TypedDict

import mujoco
import numpy as np

from bench.calibrate.apply import fixed_to
from bench.calibrate.arm.inertial import inertia_at_com, point_mass, set_std, std_params
from bench.calibrate.arm.spec import ArmSpec
from bench.core import config as config_mod
from bench.core.errors import DataError, SpecError, did_you_mean
from bench.protocols import registry
from bench.replay.spec import load_model

UNIT_RATIO = 30.0  # a torque log this many times larger (or smaller) than the model's torques has other units


class SuiteRef(TypedDict):
    """The suite whose robot an arm spec calibrates."""

    name: str
    version: str
    robot: str


class Payload(TypedDict):
    mass: float  # kg
    com: list[float]  # centre of mass in the payload frame, m


class _Values(TypedDict):
    joints: dict[str, dict[str, float]]  # full joint name -> {coulomb, viscous, armature, stiffness, gain, offset}
    links: dict[str, np.ndarray]  # link -> its rigid group's 10 standard inertial parameters (absolute)


class Values(_Values, total=False):
    """What `realise` writes into a copy of the declared model (a fit's values: `blocks.values_of`)."""

    payload: Payload


@dataclass
class ArmModel:
    """What an arm spec names, resolved in its model."""

    model: mujoco.MjModel  # the declared model, as given
    joints: list[str]  # full joint names, in the log's column order
    jids: np.ndarray
    qadr: np.ndarray
    dadr: np.ndarray
    qpos0: np.ndarray  # every other coordinate's value (a gripper, an object)
    links: list[str]  # bodies the joints move (one per joint), in joint order
    link_ids: np.ndarray
    groups: list[list[int]]  # per link: the bodies fixed to it (no joint in between), the link first
    payload_body: int  # the body the payload frame is fixed to
    payload_pos: np.ndarray  # the frame's origin in that body (3,)
    payload_rot: np.ndarray  # the frame's axes in that body (3, 3)
    payload_name: str
    motors: np.ndarray  # (n,) actuator driving each joint with a plain motor (-1: none)
    suite: SuiteRef | None  # for a suite's robot


def _suite_model(suite: str, robot: str) -> tuple[mujoco.MjModel, SuiteRef]:
    cls = registry.suite_class(suite)
    s = cls(config_mod.build(cls.Options, []))
    cells = [c for c in s.all_cells() if c.robot == robot]
    if not cells:
        robots = sorted({c.robot for c in s.all_cells()})
        raise SpecError(
            f"spec field 'model.robot': suite {suite!r} has no robot {robot!r}; robots: {', '.join(robots)}."
            f"{did_you_mean(robot, robots)}"
        )
    env = s.make_env(cells[0], s.default_horizon)
    try:
        mj = getattr(env, "mujoco", None)
        if mj is None:
            raise SpecError(f"spec field 'model': suite {suite!r} has no MuJoCo model to calibrate")
        model = copy.copy(mj.model)
    finally:
        env.close()
    return model, {"name": cls.name, "version": str(cls.version), "robot": robot}


def _joint(m: mujoco.MjModel, name: str) -> int:
    j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, name)
    if j >= 0:
        return j
    names = [m.joint(i).name for i in range(m.njnt)]
    # a prefix the model added (robosuite: robot0_joint1): one prefix token first, then any suffix match
    hits = [i for i, n in enumerate(names) if n.endswith("_" + name) and "_" not in n[: -len(name) - 1]]
    hits = hits or [i for i, n in enumerate(names) if n.endswith(name)]
    if len(hits) == 1:
        return hits[0]
    why = f"matches {len(hits)} joints ({', '.join(names[i] for i in hits)})" if hits else "is not a joint of the model"
    raise SpecError(f"spec field 'joints': {name!r} {why}; joints: {', '.join(names)}.{did_you_mean(name, names)}")


def _payload(m: mujoco.MjModel, name: str | None, last_body: int) -> tuple[int, np.ndarray, np.ndarray, str]:
    if name is None:
        return last_body, np.zeros(3), np.eye(3), m.body(last_body).name
    b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)
    if b >= 0:
        return b, np.zeros(3), np.eye(3), name
    s = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, name)
    if s >= 0:
        rot = np.zeros(9)
        mujoco.mju_quat2Mat(rot, m.site_quat[s])
        return int(m.site_bodyid[s]), np.array(m.site_pos[s]), rot.reshape(3, 3), name
    names = [m.body(i).name for i in range(m.nbody)] + [m.site(i).name for i in range(m.nsite)]
    raise SpecError(f"spec field 'payload': {name!r} is not a body or site of the model.{did_you_mean(name, names)}")


def build(spec: ArmSpec) -> ArmModel:
    """Load the declared model and resolve the spec's names in it (one SpecError naming the field otherwise)."""
    if spec.model is not None:
        model, suite = load_model(spec.model), None
    else:
        assert spec.suite and spec.robot
        model, suite = _suite_model(spec.suite, spec.robot)
    jids = np.array([_joint(model, n) for n in spec.joints])
    if len(set(jids.tolist())) != len(jids):
        raise SpecError("spec field 'joints' names one model joint twice")
    for j in jids:
        if model.jnt_type[j] not in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE):
            raise SpecError(f"spec field 'joints': {model.joint(j).name!r} is not a hinge or slide joint")
    links = [int(model.jnt_bodyid[j]) for j in jids]
    if len(set(links)) != len(links):
        raise SpecError("spec field 'joints': two joints move the same body; calibrate one joint per link")
    if spec.inertia is not None:
        names = [model.body(b).name for b in links]
        for n in spec.inertia:
            if n not in names and not any(x.endswith(n) for x in names):
                raise SpecError(f"spec field 'inertia': {n!r} is not a link the joints move; links: {', '.join(names)}")
    pb, ppos, prot, pname = _payload(model, spec.payload, links[-1])
    if not fixed_to(model, pb, links[-1]):
        raise SpecError(
            f"spec field 'payload': {pname!r} is not fixed to the last link {model.body(links[-1]).name!r} "
            "(a payload sits at the flange or a tool frame on it)"
        )
    centre, radius = np.asarray(spec.payload_region[0]), spec.payload_region[1]
    reach = float(model.stat.extent)
    if float(np.linalg.norm(centre)) - radius > reach:
        raise SpecError(
            f"spec field 'payload_region': centre {np.round(centre, 3).tolist()} m from {pname!r} with radius "
            f"{radius:g} m lies outside the model (its extent is {reach:.3g} m): the region must hold points the arm "
            "can carry"
        )
    motors = np.full(len(jids), -1)
    for a in range(model.nu):
        if model.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT and model.actuator_biastype[a] == 0:
            hit = np.flatnonzero(jids == model.actuator_trnid[a, 0])
            if hit.size:
                motors[hit[0]] = a
    data = mujoco.MjData(model)
    groups = [[b for b in range(model.nbody) if fixed_to(model, b, link)] for link in links]
    return ArmModel(
        model=model,
        joints=[model.joint(j).name for j in jids],
        jids=jids,
        qadr=model.jnt_qposadr[jids].copy(),
        dadr=model.jnt_dofadr[jids].copy(),
        qpos0=data.qpos.copy(),
        links=[model.body(b).name for b in links],
        link_ids=np.array(links),
        groups=groups,
        payload_body=pb,
        payload_pos=ppos,
        payload_rot=prot,
        payload_name=pname,
        motors=motors,
        suite=suite,
    )


def _pose_in(m: mujoco.MjModel, body: int, frame: int) -> tuple[np.ndarray, np.ndarray]:
    """Position and rotation of `body`'s frame in `frame`'s, along fixed bodies (body_pos, body_quat)."""
    pos, rot = np.zeros(3), np.eye(3)
    while body != frame:
        r = np.zeros(9)
        mujoco.mju_quat2Mat(r, m.body_quat[body])
        r = r.reshape(3, 3)
        pos, rot = m.body_pos[body] + r @ pos, r @ rot
        body = int(m.body_parentid[body])
    return pos, rot


def in_frame(p: np.ndarray, pos: np.ndarray, rot: np.ndarray) -> np.ndarray:
    """Standard parameters given in a body's frame, expressed in a frame where that body sits at (pos, rot)."""
    mass, c, ic = inertia_at_com(p)
    c2 = pos + rot @ c
    ic2 = rot @ ic @ rot.T
    io = ic2 + mass * (c2 @ c2 * np.eye(3) - np.outer(c2, c2))
    return np.array([mass, *(mass * c2), io[0, 0], io[0, 1], io[0, 2], io[1, 1], io[1, 2], io[2, 2]])


def group_std(m: mujoco.MjModel, group: list[int]) -> np.ndarray:
    """The standard parameters of a rigid group of bodies (a link and what is fixed to it), in the link's frame."""
    link = group[0]
    total = np.zeros(10)
    for b in group:
        total += in_frame(std_params(m, b), *_pose_in(m, b, link))
    return total


def check_positions(am: ArmModel, q: np.ndarray, column: str) -> None:
    """Refuse positions in other units than the model's (degrees for radians, mm for m)."""
    m = am.model
    for i, j in enumerate(am.jids):
        lo, hi = float(q[:, i].min()), float(q[:, i].max())
        hinge = m.jnt_type[j] == mujoco.mjtJoint.mjJNT_HINGE
        limit = 2 * np.pi + 0.5 if hinge else 10.0
        if max(abs(lo), abs(hi)) > limit:
            unit = "degrees? the model's hinges are in radians" if hinge else "millimetres? the model is in metres"
            raise DataError(
                f"log column {column}[{i}] (joint {am.joints[i]}) spans [{lo:.4g}, {hi:.4g}]: {unit}; "
                "convert the log before calibrating"
            )
        if m.jnt_limited[j]:
            rlo, rhi = m.jnt_range[j]
            width = rhi - rlo
            if lo < rlo - 0.5 * width or hi > rhi + 0.5 * width:
                raise DataError(
                    f"log column {column}[{i}] (joint {am.joints[i]}) spans [{lo:.4g}, {hi:.4g}], far outside the "
                    f"model's range [{rlo:.4g}, {rhi:.4g}]: another unit, another joint order or another zero?"
                )


def check_torques(am: ArmModel, tau: np.ndarray, model_tau: np.ndarray, column: str) -> None:
    """Refuse a torque log in other units (mN·m) or another joint order than the model's torques say."""
    rms_log = np.sqrt(np.mean(tau**2, axis=0))
    rms_model = np.sqrt(np.mean(model_tau**2, axis=0))
    loaded = rms_model > 0.05 * rms_model.max()
    if loaded.any():
        ratio = float(np.median(rms_log[loaded] / np.maximum(rms_model[loaded], 1e-12)))
        if ratio > UNIT_RATIO or ratio < 1.0 / UNIT_RATIO:
            guess = "mN·m (1000x)" if 300 < ratio < 3000 else "another unit"
            raise DataError(
                f"log column {column} is {ratio:.3g}x the model's torques on the loaded joints: {guess}? "
                "the model is in N·m (N for slide joints); convert the log before calibrating"
            )
    from scipy.optimize import linear_sum_assignment  # scipy: loaded only when a log is checked

    n = tau.shape[1]
    c = np.nan_to_num(np.corrcoef(np.concatenate([tau, model_tau], axis=1).T)[:n, n:])
    # the pairing of log columns with model joints that follows the model's torques best, in shape
    # (correlation) and in size (log RMS ratio); another order than the spec's, clearly better on every
    # column it moves, means the log's columns are in another order
    ratio = np.abs(np.log(np.maximum(rms_log, 1e-9)[:, None] / np.maximum(rms_model, 1e-9)[None, :]))
    cost = (1.0 - np.abs(c)) + 0.5 * ratio
    rows, cols = linear_sum_assignment(cost)
    moved = [(i, int(j)) for i, j in zip(rows, cols) if i != j and loaded[j]]
    ident = float(np.trace(cost))
    if moved and cost[rows, cols].sum() < ident - 0.5 and all(cost[i, j] < cost[i, i] - 0.2 for i, j in moved):
        i, j = moved[0]
        order = [am.joints[int(k)] for k in cols]
        raise DataError(
            f"log column {column}[{i}] follows the model's joint {am.joints[j]} (correlation {c[i, j]:+.2f}), "
            f"not {am.joints[i]} ({c[i, i]:+.2f}): the log's joint order differs from the spec's 'joints' "
            f"(the torques fit the order {', '.join(order)})"
        )


REALISED = (  # the fields `realise` writes (a scratch copy is reset to the declared model's values of these)
    "dof_frictionloss",
    "dof_damping",
    "dof_armature",
    "jnt_stiffness",
    "actuator_gainprm",
    "body_mass",
    "body_ipos",
    "body_iquat",
    "body_inertia",
    "body_sameframe",
)


def realise(am: ArmModel, values: Values, into: mujoco.MjModel | None = None) -> mujoco.MjModel:
    """A copy of the declared model carrying fitted values (or `into`, a copy made before, reset and rewritten:
    a suite's scene is costly to copy, and the bootstrap's draws realise hundreds of value sets).

    `values` holds per joint (full names) `coulomb`, `viscous`, `armature`, `stiffness`, `gain`
    (actuator gain factor), per link `std` (standard inertial parameters), and `payload`
    ({mass, com (3)} in the payload frame), each optional.
    """
    if into is None:
        m = copy.copy(am.model)
    else:
        m = into
        for name in REALISED:
            getattr(m, name)[:] = getattr(am.model, name)
    for i, j in enumerate(am.jids):
        v = values.get("joints", {}).get(am.joints[i], {})
        d = int(am.dadr[i])
        if "coulomb" in v:
            m.dof_frictionloss[d] = v["coulomb"]
        if "viscous" in v:
            m.dof_damping[d] = v["viscous"]
        if "armature" in v:
            m.dof_armature[d] = v["armature"]
        if "stiffness" in v:
            m.jnt_stiffness[j] = v["stiffness"]
        if "gain" in v and am.motors[i] >= 0:
            m.actuator_gainprm[am.motors[i], 0] = am.model.actuator_gainprm[am.motors[i], 0] * v["gain"]
    for name, p in values.get("links", {}).items():
        link = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, name)
        set_std(m, link, np.asarray(p))  # the whole rigid group's parameters, carried by the link itself
        for b in am.groups[am.links.index(name)][1:]:
            m.body_mass[b], m.body_inertia[b] = 0.0, 0.0
    pay = values.get("payload")
    if pay:
        com_body = am.payload_pos + am.payload_rot @ np.asarray(pay["com"], dtype=np.float64)
        b = am.payload_body
        set_std(m, b, std_params(m, b) + point_mass(float(pay["mass"]), com_body))
    if into is None:  # a scratch copy only holds values; a model that will be stepped gets its derived constants
        mujoco.mj_setConst(m, mujoco.MjData(m))
    return m


def require_motors(am: ArmModel) -> str | None:
    """Why the forward-simulation check cannot drive the joints with the logged torque, or None."""
    missing = [am.joints[i] for i in range(len(am.jids)) if am.motors[i] < 0]
    if missing:
        return f"joints without a plain motor actuator: {', '.join(missing)}"
    gears = am.model.actuator_gear[am.motors, 0]
    if np.any(gears == 0):
        return "a motor with gear 0"
    return None
