"""The MJX Lift suite (suites/mjx_lift.py): robosuite's arms in MJX, N worlds per call, one record per world,
per-world calibration draws, bad input refused.

Needs the mjx extra; skipped without it. Small on purpose: JAX compiles each arm and world count once (tens of
seconds on this CPU, then cached on disk), so the fast tests compile nothing and the runs are marked slow.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bench.cli import main
from bench.core.errors import ConfigError
from bench.records import read_records

pytest.importorskip("mujoco.mjx")
pytest.importorskip("robosuite")

CALIBRATION = Path(__file__).resolve().parent.parent / "results" / "real_panda" / "calibration"  # a real Panda's


def _run(tmp_path, *extra: str, episodes: int = 2) -> int:
    return main(["run", "suite=mjx_lift", f"episodes={episodes}", "horizon=60", "seed=3", f"out={tmp_path}", *extra])


@pytest.mark.slow
def test_vector_run_gives_one_record_per_world_like_vector_1(tmp_path):
    assert _run(tmp_path, "robots=[Panda]", "workers=1", "vector=2", "run_id=two") == 0
    assert _run(tmp_path, "robots=[Panda]", "workers=1", "vector=1", "run_id=one") == 0
    two = sorted(read_records(tmp_path / "two" / "episodes.jsonl"), key=lambda r: r.episode)
    one = sorted(read_records(tmp_path / "one" / "episodes.jsonl"), key=lambda r: r.episode)
    assert [r.episode for r in two] == [0, 1]
    assert len({r.init_state_hash for r in two}) == 2  # each world its own cube from its episode seed
    assert all(r.success_once and r.error is None for r in two)  # the batched expert lifts the cube
    assert [r.init_state_hash for r in one] == [r.init_state_hash for r in two]
    # a world stepped alone and in a batch of 2: the same outcome (float32 batches may differ in the last bits)
    assert [(r.success_once, r.steps_to_success) for r in one] == [(r.success_once, r.steps_to_success) for r in two]
    assert all(r.backend.startswith("mjx-") for r in two)


@pytest.mark.slow
@pytest.mark.parametrize("arm", ["UR5e", "Kinova3"])
def test_the_expert_lifts_on_held_out_arms(tmp_path, arm):
    assert _run(tmp_path, f"robots=[{arm}]", "workers=1", "vector=2", "run_id=r") == 0
    records = list(read_records(tmp_path / "r" / "episodes.jsonl"))
    assert len(records) == 2 and all(r.split == "unseen" and r.success_once for r in records)


@pytest.mark.slow
def test_from_calibration_gives_each_world_its_own_recorded_draw(tmp_path):
    axis = f"perturb.damping=from({CALIBRATION})"
    assert _run(tmp_path, "robots=[Panda]", "workers=1", "vector=4", axis, "run_id=cal", episodes=4) == 0
    records = [r for r in read_records(tmp_path / "cal" / "episodes.jsonl") if "from(" in str(r.condition)]
    assert len(records) == 4 and all(r.error is None for r in records)
    draws = [r.params["damping.draw"] for r in records]
    assert len(set(draws)) > 1  # each world its own draw, recorded
    assert len({r.params["damping"] for r in records}) == len(set(draws))


def test_the_split_is_held_out_robots():
    from suites.held_out_robots import SEEN, UNSEEN
    from suites.mjx_lift import MjxLift

    cells = MjxLift().all_cells()
    assert [c.robot for c in cells if c.split == "seen"] == SEEN
    assert [c.robot for c in cells if c.split == "unseen"] == UNSEEN


@pytest.mark.parametrize("arm", ["Panda", "Sawyer", "IIWA", "UR5e", "Kinova3", "Jaco", "XArm7"])
def test_every_arm_builds_with_its_joints_first_and_the_contacts_pruned(arm):
    import mujoco

    from bench.sims.mjx_lift import ARMS, scene

    m = scene.build(arm)
    joints = ARMS[arm].joints
    assert m.njnt == len(joints) + 3  # the arm's, two fingers, the cube's free joint (Sawyer's head pan welded)
    assert [int(m.jnt_dofadr[m.joint(j).id]) for j in joints] == list(range(len(joints)))
    assert not np.any(m.jnt_limited[: len(joints)]) and not np.any(m.dof_frictionloss)
    data = mujoco.MjData(m)
    data.qpos[: len(joints)] = ARMS[arm].home
    mujoco.mj_forward(m, data)
    grip = data.site_xpos[m.site("grip").id]
    assert (
        0.85 < grip[2] < 1.25 and abs(grip[0]) < 0.25 and abs(grip[1]) < 0.2
    )  # over the table (robosuite: Sawyer 17 cm aside)
    pairs = {
        tuple(sorted((int(m.geom_bodyid[i]), int(m.geom_bodyid[j]))))
        for i in range(m.ngeom)
        for j in range(i + 1, m.ngeom)
        if (m.geom_contype[i] & m.geom_conaffinity[j]) or (m.geom_contype[j] & m.geom_conaffinity[i])
    }
    cube = m.body("cube").id
    assert pairs == {(0, cube), *((m.body(f"finger_{s}").id, cube) for s in ("left", "right"))}  # table is world


def test_gains_follow_each_arms_inertia():
    from bench.sims.mjx_lift import scene

    kp = {}
    for arm in ("Panda", "Kinova3"):
        m = scene.build(arm)
        kp[arm], kd = scene.gains(m, arm, np.arange(len(scene.ARMS[arm].joints)))
        assert np.all(kp[arm] >= scene.KP_RANGE[0]) and np.all(kp[arm] <= scene.KP_RANGE[1]) and np.all(kd > 0)
    assert kp["Panda"][0] > kp["Kinova3"][0]  # the Panda's shoulder carries more inertia than the Kinova Gen3's


def test_profiling_solver_settings_reach_the_compiled_model_and_the_suite_keeps_its_own():
    import mujoco

    from bench.sims.mjx_lift import control, scene

    suite = control.Compiled("Panda").model.opt
    assert suite.solver == mujoco.mjtSolver.mjSOL_NEWTON and suite.iterations == scene.ITERATIONS
    assert not suite.disableflags & mujoco.mjtDisableBit.mjDSBL_WARMSTART
    variant = control.Compiled("Panda", iterations=2, cg=True, warmstart=False, tolerance=1e-12)
    opt = variant.model.opt
    assert opt.solver == mujoco.mjtSolver.mjSOL_CG and opt.iterations == 2 and opt.tolerance == 1e-12
    assert opt.disableflags & mujoco.mjtDisableBit.mjDSBL_WARMSTART
    assert variant.mx.opt.solver.value == int(mujoco.mjtSolver.mjSOL_CG)  # what MJX steps with


def test_an_axis_mjx_cannot_express_is_refused_before_the_run(tmp_path, capsys):
    assert _run(tmp_path, "robots=[Panda]", "perturb.frictionloss=[0.5]", "run_id=bad") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "perturb.frictionloss" in err
    assert "damping, friction, link_mass, mass" in err
    assert not (tmp_path / "bad").exists()


def test_a_world_count_beyond_memory_is_refused_in_one_line_with_the_estimate():
    from bench.sims import mjx_lift  # the MJX scene: only with the extra (importorskip above)

    need, per = mjx_lift.memory_estimate(1)
    assert 10_000 < per < 10_000_000 and need == per  # from the model's MJX data: kB per world, not bytes or GB
    mjx_lift.check_worlds(1024, available=2**34)  # 16 GiB holds 1,024 worlds
    with pytest.raises(ConfigError) as e:
        mjx_lift.check_worlds(10**6, available=2**34, per="vector=500000 x workers=2")
    msg = str(e.value)
    assert msg.startswith("worlds=1000000 (vector=500000 x workers=2)") and "\n" not in msg
    assert f"{per / 1e3:.0f} kB per world" in msg and f"at most {2**34 // per} worlds" in msg


def test_a_run_over_memory_writes_nothing(tmp_path, capsys):
    argv = ["robots=[Panda]", "episodes=65536", "vector=65536", "workers=64", "horizon=1", "run_id=big"]
    assert main(["run", "suite=mjx_lift", f"out={tmp_path}", *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "worlds=4194304 (vector=65536 x workers=64)" in err and "GiB" in err
    assert not (tmp_path / "big").exists()


def test_calibration_draws_land_in_their_own_world_only():
    if not (CALIBRATION / "calibration.json").exists():
        pytest.skip(f"no calibration at {CALIBRATION}")
    from bench.sims.mjx_lift import LiftBatch

    draws = json.loads((CALIBRATION / "calibration.json").read_text())["draws"]
    keys = [k for k in draws["keys"] if k.startswith("dof_damping:")]
    rows = [[v for k, v in zip(draws["keys"], row) if k.startswith("dof_damping:")] for row in draws["values"][:2]]
    batch = LiftBatch("Panda")
    a, b = batch.add(10), batch.add(10)
    ratio = a.write_draw("damping", keys, rows[0])
    b.write_draw("damping", keys, rows[1])
    damping = batch.fields["dof_damping"]
    assert np.allclose(damping[0, :7], rows[0]) and np.allclose(damping[1, :7], rows[1])
    assert not np.allclose(damping[0], damping[1])
    assert ratio == pytest.approx(np.mean(np.asarray(rows[0]) / batch.c.nominal["dof_damping"][:7]), rel=1e-5)
    a.restore()
    assert np.allclose(damping[0], batch.c.nominal["dof_damping"]) and np.allclose(damping[1, :7], rows[1])


def test_a_calibration_of_another_robot_is_refused():
    from bench.sims.mjx_lift import LiftBatch

    world = LiftBatch("Kinova3").add(10)
    with pytest.raises(ConfigError, match="does not have .a calibration of another robot"):
        world.write_draw("damping", ["dof_damping:robot0_joint1"], [0.1])


def test_batched_expert_is_stateless_and_batched():
    from baselines.mjx_lift_expert import BatchLiftExpert  # beside the suite: only once the extra is there
    from bench.sims.mjx_lift import OBS_FIELDS  # imports MuJoCo's MJX helpers: only with the extra

    expert = BatchLiftExpert(OBS_FIELDS)
    obs = np.zeros(18, np.float32)
    obs[0:3], obs[7], obs[8:11] = (0.0, 0.0, 0.83), 0.4, (0.0, 0.0, 0.82)  # closed on the cube: lift
    far = obs.copy()
    far[8:11] = (0.1, 0.0, 0.82)  # away from the cube, open: hover
    far[7] = 1.0
    batch = expert.act_batch([{"state": obs}, {"state": far}])
    assert batch.shape == (2, 7)
    assert batch[0, 2] > 0 and batch[0, 6] == 1.0 and batch[1, 6] == -1.0
    assert np.array_equal(expert.act({"state": far}), batch[1])
    above = far.copy()
    above[8:11], above[0:3] = (0.0, 0.0, 0.82), (0.0, 0.0, 0.9)  # centred above the cube, open: descend, open
    at = far.copy()
    at[8:11], at[0:3] = (0.0, 0.0, 0.82), (0.0, 0.0, 0.825)  # centred at its height, open: close
    phases = expert.act_batch([{"state": above}, {"state": at}])
    assert phases[0, 2] < 0 and phases[0, 6] == -1.0 and phases[1, 6] == 1.0
    assert batch.dtype == np.float32 and not batch[:, 3:6].any()  # rotation deltas 0
    many = [{"state": o} for o in (obs, far, above, at) * 256]  # 1,024 worlds in one call: each its own answer
    assert np.array_equal(expert.act_batch(many), np.tile(np.vstack([batch, phases]), (256, 1)))


def _gpu() -> str | None:
    """Why the CPU/GPU agreement test cannot run here, or None when a GPU JAX device is present."""
    try:
        import jax
    except ImportError:
        return "JAX is not installed"
    try:
        jax.devices("gpu")
    except RuntimeError:
        return "no GPU JAX device (this test compares CPU JAX with a GPU; CPU-only CI skips it)"
    return None


STATE_TOL = 2e-3  # m / rad: float32 worlds on two backends drift apart by XLA's operation order, not physics


@pytest.mark.skipif(_gpu() is not None, reason=str(_gpu()))
def test_cpu_and_gpu_agree_per_world():
    """The same seeds on CPU JAX and on the GPU: the same per-world success, states within STATE_TOL."""
    import jax

    from baselines.mjx_lift_expert import BatchLiftExpert
    from bench.sims.mjx_lift import OBS_FIELDS, LiftBatch

    out = {}
    for platform in ("cpu", "gpu"):
        with jax.default_device(jax.devices(platform)[0]):
            batch = LiftBatch("Panda")
            worlds = [batch.add(60) for _ in range(8)]
            obs = [w.reset(100 + i) for i, w in enumerate(worlds)]
            expert, lifted = BatchLiftExpert(OBS_FIELDS), np.zeros(8, bool)
            for _ in range(60):
                act = expert.act_batch(obs)
                batch.step_all(dict(enumerate(act)))
                obs = [w.step(a)[0] for w, a in zip(worlds, act)]
                lifted |= batch.lifted()
            out[platform] = (lifted, batch.qpos.copy())
    assert np.array_equal(out["cpu"][0], out["gpu"][0])
    assert np.max(np.abs(out["cpu"][1] - out["gpu"][1])) < STATE_TOL


def _top_speeds(batch, steps: int, expert: bool = False) -> np.ndarray:
    """Step every world of `batch` `steps` control steps (zero actions, or the batched expert's); the largest
    |qvel| seen per dof over the worlds (inf once a world turns non-finite)."""
    from baselines.mjx_lift_expert import BatchLiftExpert
    from bench.sims.mjx_lift import OBS_FIELDS

    policy, top = BatchLiftExpert(OBS_FIELDS), np.zeros(batch.nv)
    for _ in range(steps):
        n = len(batch.worlds)
        actions = policy.act_batch([{"state": o} for o in batch.obs]) if expert else np.zeros((n, 7), np.float32)
        batch.step_all(dict(enumerate(actions)))
        if not (np.isfinite(batch.qpos).all() and np.isfinite(batch.qvel).all()):
            return np.full(batch.nv, np.inf)
        top = np.maximum(top, np.abs(batch.qvel).max(axis=0))
    return top


@pytest.mark.slow
def test_iiwa_stays_finite_with_its_shoulder_joints_aligned():
    """At q2 -> 0 the IIWA's joints 1 and 3 align and the impedance's damping, applied explicitly, had
    dt * max eig(M^-1 Kd) = 2.5 > 2 (unstable): 10 of 64 expert worlds went non-finite while re-grasping. The
    damping is now the joints' dof_damping, integrated implicitly: a small twist of that mode dies out (explicit:
    joints 1 and 3 at +70 / -81 rad/s after one control step)."""
    from bench.sims.mjx_lift import LiftBatch

    batch = LiftBatch("IIWA")
    batch.add(10).reset(0)
    batch.qpos[0, 1] = 0.05  # shoulder nearly upright: joints 1 and 3 aligned
    batch.qvel[0, 0], batch.qvel[0, 2] = 0.1, -0.1  # a twist of the aligned pair (the mode that blew up)
    top = _top_speeds(batch, 5)
    assert np.all(np.isfinite(top)) and max(top[0], top[2]) < 1.0  # rad/s: the aligned pair stays slow


@pytest.mark.slow
def test_link_mass_draws_are_written_as_on_mujoco_cpu_and_stay_finite():
    """`perturb.link_mass=from(real_panda)`: each world gets the draw's values verbatim, as the MuJoCo CPU path's
    `write_fields` writes them (principal inertias of exactly 0 included: robot0_right_hand's in every draw; no
    floor there either), and the worlds stay finite: draws 106 and 167 went non-finite at steps 1-3 when the
    impedance's damping was applied explicitly (wrist inertias 10-50x below the nominal ones the gains use)."""
    if not (CALIBRATION / "calibration.json").exists():
        pytest.skip(f"no calibration at {CALIBRATION}")
    from bench.sims.mjx_lift import LiftBatch
    from bench.sims.perturb.axes import FROM_FIELDS

    draws = json.loads((CALIBRATION / "calibration.json").read_text())["draws"]
    keep = [i for i, k in enumerate(draws["keys"]) if k.split(":")[0] in FROM_FIELDS["link_mass"]]
    keys = [draws["keys"][i] for i in keep]
    batch = LiftBatch("Panda")
    for seed, k in enumerate((106, 167)):
        world = batch.add(10)
        world.write_draw("link_mass", keys, [draws["values"][k][i] for i in keep])
        world.reset(seed)
    hand = batch.c.model.body("right_hand").id
    row = keys.index("body_inertia:robot0_right_hand:0")
    assert draws["values"][167][keep[row]] == 0.0 and batch.fields["body_inertia"][1, hand, 0] == 0.0  # verbatim
    assert np.all(np.isfinite(_top_speeds(batch, 5, expert=True)))


def test_draw_writing_and_world_checks_are_declared_capabilities():
    """perturb writes a calibration draw into backends declaring `WritesDraws`, and the planner asks every suite
    `check_worlds` (SuiteBase: any count fits): protocol members, not getattr probes."""
    from bench.protocols import WritesDraws
    from bench.protocols.suite import SuiteBase
    from bench.sims.mjx_lift import LiftBatch
    from suites.mjx_lift import MjxLift

    class ScalesOnly:  # a ModelAxes without the capability
        axes = frozenset({"mass"})

        def restore(self) -> None: ...

        def apply(self, axis, scale, targets) -> None: ...

    world = LiftBatch("Panda").add(10)
    assert isinstance(world.model_axes, WritesDraws) and not isinstance(ScalesOnly(), WritesDraws)

    class Plain(SuiteBase):
        def all_cells(self):
            return []

        def obs_spec(self, cell):
            return {}

        def make_env(self, cell, horizon):
            raise AssertionError

    assert Plain().check_worlds([], 10**9, 64) is None  # the default accepts any count
    cells = [c for c in MjxLift().all_cells() if c.robot == "Panda"]
    with pytest.raises(ConfigError, match=r"^worlds=4194304 \(vector=65536 x workers=64\)"):
        MjxLift().check_worlds(cells, 65536, 64)
