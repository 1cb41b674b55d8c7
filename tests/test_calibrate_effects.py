"""The effect library: every effect is nested (zero = absent) and realised in the simulation itself."""

import json
from dataclasses import replace
from pathlib import Path

import mujoco
import numpy as np
import pytest

from bench.calibrate.data import extract
from bench.calibrate.effects import EFFECTS, Target, deadband, saturate, saturation_limit, stribeck_force
from bench.calibrate.generate import declared_files, simulate_arm
from bench.calibrate.model import Candidate, Layout, Plant
from bench.calibrate.report import clean
from bench.calibrate.spec import load_spec
from bench.replay.simulate import free_runs, horizons
from bench.replay.spec import load_model


@pytest.fixture(scope="module")
def plant(tmp_path_factory) -> Plant:
    spec = load_spec(declared_files(tmp_path_factory.mktemp("fx"), None))
    eps, _ = simulate_arm(None, episodes=2, duration=1.5, seed=3)
    model = load_model(spec.model)
    rec = extract(spec, eps, 100.0, nq=model.nq, nv=model.nv, nu=model.nu)
    return Plant(spec, model, rec)


def _candidate(plant: Plant, name: str) -> Candidate:
    """The effect on the arm's middle joint / actuator, or its last link (built directly: the loop
    itself skips families the spec declares free and offers Stribeck / asymmetric only over Coulomb)."""
    eff = EFFECTS[name]
    kind = "joint" if eff.kind == "joint" else eff.kind
    target = {
        "joint": plant.targets("joint")[1],
        "actuator": plant.targets("actuator")[1],
        "body": plant.targets("body")[2],
    }[kind]
    if name == "input_channel":
        target = Target("joint", target.name, target.index, target.dof, target.joint, 0, plant.rec.input_names[0])
    return Candidate(eff, target, eff.bounds(plant.scales, target))


@pytest.mark.parametrize("name", list(EFFECTS))
def test_effect_is_nested_and_realised_in_simulation(plant, name):
    cand = _candidate(plant, name)
    sim = plant.simulator()
    segs = horizons(plant.rec, plant.rec.train, 20)
    declared = plant.declared_init()
    base = sim.run([Layout(plant, []).realise(declared)], segs)[0]
    off = Layout(plant, [cand]).realise(np.concatenate([declared, cand.start()]))
    on_x = cand.start()
    on_x[: cand.effect.n_nested] = [0.5 * hi if hi > 0 else 0.5 * lo for lo, hi in cand.bounds[: cand.effect.n_nested]]
    on = Layout(plant, [cand]).realise(np.concatenate([declared, on_x]))
    zero, moved = sim.run([off, on], segs)
    assert np.allclose(zero, base, atol=1e-9), f"{name} at zero must equal the declared model"
    assert np.abs(moved - base).max() > 1e-3, f"{name} switched on must move the simulated output"
    lo = [b[0] for b in cand.bounds]
    hi = [b[1] for b in cand.bounds]
    assert all(a < b for a, b in zip(lo, hi))
    sim.close()


@pytest.mark.parametrize("name, field", [("armature", "dof_armature"), ("payload_mass", "body_mass")])
def test_mass_edits_reach_the_mass_matrix(plant, name, field):
    cand = _candidate(plant, name)
    declared = plant.declared_init()
    mats = []
    for x in (0.0, 0.3):
        v = Layout(plant, [cand]).realise(np.concatenate([declared, [x]]))
        d = mujoco.MjData(v.model)
        d.qpos[:] = [0.2, -0.3, 0.4]
        mujoco.mj_forward(v.model, d)
        m = np.zeros((v.model.nv, v.model.nv))
        mujoco.mj_fullM(v.model, m, d.qM)
        mats.append(m)
    assert np.abs(mats[1] - mats[0]).max() > 0.05
    assert np.allclose(getattr(plant.model, field), getattr(Layout(plant, []).realise(declared).model, field))


def test_stepped_and_batched_rollouts_agree_without_stribeck(plant):
    """The stepped path (used for Stribeck friction) integrates exactly like one rollout call."""
    sim = plant.simulator()
    v = Layout(plant, []).realise(plant.declared_init())
    segs = free_runs(plant.rec, plant.rec.train[:1])
    a = sim.run([replace(v, force=None)], segs)  # no force hook: one rollout call
    b = sim.run([replace(v, force=lambda q, qd, u: np.zeros_like(qd))], segs)  # a (zero) force: stepped
    assert np.allclose(a, b, atol=1e-9)


def test_primitives():
    u = np.array([-2.0, -0.5, 0.0, 0.3, 3.0])
    assert np.allclose(deadband(u, 0.5), [-1.5, 0.0, 0.0, 0.0, 2.5])
    assert np.allclose(saturate(u, 1.0), [-1.0, -0.5, 0.0, 0.3, 1.0])
    v = np.array([-1.0, 0.0, 1e-6, 5.0])
    f = stribeck_force(v, 0.5, 0.1)
    assert f[1] == 0.0 and abs(f[2]) < 1e-9 and np.isclose(f[3], 0.5) and np.isclose(f[0], -0.5)


def test_saturation_share_is_a_quantile(plant):
    s = plant.scales
    limits = [saturation_limit(share, s, 1) for share in (0.0, 0.1, 0.5, 0.9)]
    assert np.isclose(limits[0], s.ctrl_max[1])
    assert limits == sorted(limits, reverse=True)
    assert np.isclose(np.mean(np.abs(plant.rec.ctrl[:, 1]) > limits[2]), 0.5, atol=0.01)


def test_delay_shifts_the_applied_command(plant):
    s = plant.substeps
    shifted = plant._delayed(plant.base_ctrl[:, 0], 2 * s)  # two frames
    n = plant.rec.offsets[1] * s
    assert np.allclose(shifted[2 * s : n], plant.base_ctrl[: n - 2 * s, 0])
    assert np.allclose(shifted[: 2 * s], plant.base_ctrl[0, 0])  # held at the episode start


def test_generator_is_deterministic():
    a, ta = simulate_arm("bias", episodes=2, duration=0.5, seed=7)
    b, tb = simulate_arm("bias", episodes=2, duration=0.5, seed=7)
    c, _ = simulate_arm("bias", episodes=2, duration=0.5, seed=8)
    assert ta == tb
    for x, y in zip(a, b):
        for k in x:
            assert np.array_equal(x[k], y[k])
    assert not np.array_equal(a[0]["action"], c[0]["action"])


def test_clean_has_no_nan():
    doc = clean({"a": float("nan"), "b": [np.float32(np.inf), np.int64(3)], "c": np.array([1.0, np.nan])})
    assert doc == {"a": None, "b": [None, 3], "c": [1.0, None]}
    json.dumps(doc, allow_nan=False)


def test_collinear_declared_parameters_are_flagged(tmp_path):
    """On a slide joint, carriage mass and armature are the same inertia: the fit must say so."""
    from bench.calibrate.fit import Objective, fit
    from bench.calibrate.generate import MODELS
    from bench.calibrate.spec import parse_spec

    rng = np.random.default_rng(0)
    model = mujoco.MjModel.from_xml_path(str(MODELS / "emps.xml"))
    d = mujoco.MjData(model)
    u = np.repeat(rng.normal(0.0, 2.0, 40), 25)  # piecewise-constant drive command [V], 1 kHz
    q = np.empty(len(u))
    for i, ui in enumerate(u):
        q[i] = d.qpos[0]
        d.ctrl[0] = ui
        mujoco.mj_step(model, d)
    raw = {
        "model": "emps.xml",
        "substeps": 1,
        "signals": {"qpos": {"column": "q", "index": [0]}, "ctrl": {"column": "u", "index": [0]}},
        "params": [
            {"name": "mass", "field": "body_mass", "elements": ["carriage"], "bounds": [10, 300]},
            {"name": "armature", "field": "dof_armature", "elements": ["axis"], "bounds": [0, 100]},
        ],
    }
    spec = parse_spec(raw, base_dir=MODELS)
    rec = extract(spec, [{"q": q, "u": u}], 1000.0, nq=1, nv=1, nu=1)
    plant = Plant(spec, load_model(spec.model), rec)
    sim = plant.simulator()
    scale = np.array([q.std(), 1.0])
    f = fit(
        Objective(sim, Layout(plant, []), horizons(rec, rec.train, 200), rec, scale, np.arange(1)),
        plant.declared_init(),
    )
    assert any("ill-conditioned" in w or "not identifiable" in w for w in f.warnings), f.warnings
    assert any("armature" in w and "mass" in w for w in f.warnings), f.warnings


def test_play_model_appends_a_rotor_and_keeps_every_index():
    """Backlash rebuilds the model: a rotor body, joint and tendon are appended; nothing else moves."""
    from bench.calibrate.generate import ARM
    from bench.calibrate.play import build, coordinates, set_play

    base = mujoco.MjModel.from_xml_path(str(ARM))
    for side in ("link", "motor"):
        pm = build(ARM, ((1, side),), base)
        m = pm.model
        assert (m.nq, m.nv, m.nu, m.ntendon) == (4, 4, 3, 1)
        for obj, n in ((mujoco.mjtObj.mjOBJ_BODY, base.nbody), (mujoco.mjtObj.mjOBJ_JOINT, base.njnt)):
            names = [mujoco.mj_id2name(base, obj, i) for i in range(n)]
            assert [mujoco.mj_id2name(m, obj, i) for i in range(n)] == names
        p = pm.play(1)
        assert m.actuator_trnid[1, 0] == 3 and m.actuator_trnid[0, 0] == 0  # m2 drives the rotor now
        set_play(m, p, 0.04, 1.0)
        assert np.allclose(m.tendon_range[p.tendon], [-0.02, 0.02])
        assert m.dof_armature[p.rotor_dof] == base.dof_armature[1] and m.dof_armature[p.link_dof] == 0.0
        c = coordinates(m, [(p, 0.04)], 3, warmup=0)
        assert list(c.qpos_adr) == ([0, 1, 2] if side == "link" else [0, 3, 2])
        q, v = c.init(
            np.array([0]), np.array([[0.1, 0.2, 0.3]]), np.array([[1.0, 2.0, 3.0]]), np.array([[0.0, 5.0, 0.0]])
        )
        assert np.allclose(q[0, 3] - q[0, 1], 0.02)  # pushing forwards: the rotor leads by half the play
        assert np.allclose(q[0, c.qpos_adr], [0.1, 0.2, 0.3]) and np.allclose(v[0, [1, 3]], 2.0)


def test_warm_up_finds_the_side_the_log_does_not_measure(tmp_path):
    """At the true play, simulating a few frames before each horizon beats guessing the unlogged side."""
    from dataclasses import replace

    from bench.calibrate.fit import Objective

    effect = "backlash_motor"
    eps, truth = simulate_arm(effect, episodes=2, duration=2.0, seed=1)
    spec = load_spec(declared_files(tmp_path, effect))
    model = load_model(spec.model)
    p = Plant(spec, model, extract(spec, eps, 100.0, nq=3, nv=3, nu=3))
    target = p.targets("actuator")[1]
    cand = Candidate(EFFECTS[effect], target, EFFECTS[effect].bounds(p.scales, target))
    layout = Layout(p, [cand])
    x = np.array([0.4, 0.3, 0.15, truth.params["play"]])  # the generator's damping and play
    sim = p.simulator()
    segs = horizons(p.rec, p.rec.train, 20)
    scale = np.concatenate([p.rec.qpos, p.rec.qvel], axis=1).std(axis=0)
    obj = Objective(sim, layout, segs, p.rec, scale, np.arange(6))
    warm = layout.realise(x)
    assert warm.coords is not None and warm.coords.warmup == 10
    cold = replace(warm, coords=replace(warm.coords, warmup=0))
    errs = [
        float(np.sqrt(np.mean(((sim.run([v], segs)[0] - obj.target) * obj.weight)[obj.mask] ** 2)))
        for v in (warm, cold)
    ]
    sim.close()
    assert errs[0] < 0.8 * errs[1], errs  # measured: 0.051 with the warm-up, 0.073 without


def test_spring_reports_its_rest_position_with_a_delta_method_interval(plant):
    eff, t = EFFECTS["joint_spring"], plant.targets("joint")[1]
    x = np.array([4.0, 1.6])  # stiffness, preload: rest position 0.4 (the model's reference is 0)
    cov = np.array([[0.01, 0.002], [0.002, 0.004]])
    assert eff.physical(x, plant.scales, t) == pytest.approx({"stiffness": 4.0, "reference": 0.4})
    iv = eff.intervals(x, cov, plant.scales, t)
    g = np.array([-1.6 / 16, 1 / 4])
    half = 1.96 * np.sqrt(g @ cov @ g)
    assert iv["reference"] == pytest.approx([0.4 - half, 0.4 + half])
    assert iv["stiffness"] == pytest.approx([4 - 1.96 * 0.1, 4 + 1.96 * 0.1])
    assert eff.intervals(np.array([0.0, 1.0]), cov, plant.scales, t)["reference"] is None  # no stiffness, no rest
    assert eff.gated == (0,) and "bias" in eff.extends and eff.standalone


def test_an_effect_is_one_row_the_generator_and_the_spec_read():
    """Each effect carries what the generator plants (a target of arm3.xml and physical parameters) and which
    of its parameters stop being physical below zero; no other table is keyed by effect name."""
    arm = mujoco.MjModel.from_xml_path(str(Path(__file__).resolve().parents[1] / "bench/calibrate/models/arm3.xml"))
    kinds = {
        "joint": mujoco.mjtObj.mjOBJ_JOINT,
        "actuator": mujoco.mjtObj.mjOBJ_ACTUATOR,
        "body": mujoco.mjtObj.mjOBJ_BODY,
    }
    for name, eff in EFFECTS.items():
        target, params = eff.example
        assert mujoco.mj_name2id(arm, kinds[eff.kind], target) >= 0, name
        assert params and (eff.plant is not None or set(params) == set(eff.params)), name
        assert set(eff.limits) <= set(eff.params), name
    import bench.calibrate.generate as generate

    assert not hasattr(generate, "DEFAULTS") and not hasattr(generate, "GEARED")
