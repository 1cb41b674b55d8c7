"""MJX backend (the `mjx` extra): refusals before any work, batched replay equal to the CPU path, gradient fits.

Tests that step MJX compile for 10-100 s on a CPU the first time a shape is seen (JAX's disk cache,
$BENCH_JAX_CACHE, keeps them across runs); the default suite keeps one small equality check and the
refusals, the rest is marked slow.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pytest

from bench.calibrate.generate import write_case
from bench.replay.data import Recording, Window
from bench.replay.simulate import Segments, Simulator, Variant, hold

REPO = Path(__file__).resolve().parents[1]
ARM = REPO / "bench/calibrate/models/arm3.xml"
SHARED = REPO.parent / "shared"

try:
    import jax  # noqa: F401  JAX: the mjx extra
    from mujoco import mjx  # noqa: F401  mujoco-mjx: the mjx extra

    HAVE_MJX = True
except ImportError:
    HAVE_MJX = False
needs_mjx = pytest.mark.skipif(not HAVE_MJX, reason='needs the mjx extra (pip install -e ".[mjx]": JAX, mujoco-mjx)')


def bench(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bench", *args], capture_output=True, text=True, cwd=REPO)


def _with(xml: str, old: str, new: str, tmp: Path, name: str = "m.xml") -> Path:
    path = tmp / name
    path.write_text(xml.replace(old, new))
    return path


@pytest.fixture(scope="module")
def case(tmp_path_factory) -> Path:
    """A small generated arm case (hidden viscous damping on j2)."""
    out = tmp_path_factory.mktemp("mjx") / "case"
    write_case(out, "viscous_damping", episodes=3, duration=1.0, fps=100.0, seed=0)
    return out


# --- bad input: refused in one line before any work -------------------------------------------------------
@needs_mjx
def test_unsupported_option_is_named(tmp_path):
    from bench.core.errors import SpecError
    from bench.sims.mjx import check_model, unsupported

    xml = ARM.read_text()
    m = mujoco.MjModel.from_xml_string(xml.replace('integrator="implicitfast"', 'integrator="implicit"'))
    assert unsupported(m).startswith("option integrator=implicit (MJX supports")
    with pytest.raises(SpecError, match=r"spec field 'model': MJX cannot simulate .*integrator=implicit"):
        check_model(m)
    assert unsupported(mujoco.MjModel.from_xml_path(str(ARM))) is None


@needs_mjx
def test_unsupported_geom_pair_is_named():
    from bench.sims.mjx import unsupported

    xml = """<mujoco><worldbody>
      <geom name="floor_box" type="box" size="1 1 0.1"/>
      <body pos="0 0 1"><freejoint/><geom name="can" type="cylinder" size="0.1 0.2"/></body>
    </worldbody></mujoco>"""
    problem = unsupported(mujoco.MjModel.from_xml_string(xml))
    assert "geom 'can' (cylinder) against geom 'floor_box' (box)" in problem
    assert "no collision function" in problem


@needs_mjx
def test_replay_and_calibrate_refuse_an_unsupported_model_before_writing(case, tmp_path):
    spec = case / "spec.yaml"
    bad_model = _with(
        (case / "arm3_declared.xml").read_text(), 'integrator="implicitfast"', 'integrator="implicit"', case, "bad.xml"
    )
    bad_spec = tmp_path / "bad.yaml"
    bad_spec.write_text(spec.read_text().replace("arm3_declared.xml", str(bad_model)))
    out = tmp_path / "out"
    r = bench("replay", f"logs={case / 'logs'}", f"spec={bad_spec}", "backend=mjx", f"out={out}")
    assert r.returncode == 2, r.stderr
    lines = [ln for ln in r.stderr.strip().splitlines() if ln]
    assert len(lines) == 1 and "integrator=implicit" in lines[0] and "backend=mujoco" in lines[0], r.stderr
    r = bench("calibrate", f"spec={bad_spec}", f"logs={case / 'logs'}", f"out={out}", "method=gradient")
    assert r.returncode == 2 and "integrator=implicit" in r.stderr and "least_squares" in r.stderr, r.stderr
    assert not out.exists()


def test_unknown_method_and_backend_are_refused(case, tmp_path):
    r = bench(
        "calibrate", f"spec={case / 'spec.yaml'}", f"logs={case / 'logs'}", f"out={tmp_path / 'o'}", "method=gradiant"
    )
    assert r.returncode == 2 and "key 'method'" in r.stderr and "least_squares, gradient" in r.stderr
    assert "did you mean 'gradient'" in r.stderr.lower()
    r = bench("replay", f"logs={case / 'logs'}", f"spec={case / 'spec.yaml'}", "backend=gpu")
    assert r.returncode == 2 and "key 'backend'" in r.stderr and "mujoco, mjx" in r.stderr
    r = bench("replay", f"logs={case / 'logs'}", f"spec={case / 'spec.yaml'}", "perturb.latency=[2]")
    assert r.returncode == 2 and "perturb.latency" in r.stderr and "model axes" in r.stderr
    assert not (tmp_path / "o").exists()


def test_missing_jax_names_the_extra(monkeypatch):
    from bench.core.errors import ConfigError
    from bench.sims import mjx as backend

    monkeypatch.setattr(backend, "_state", {})
    monkeypatch.setenv("XLA_FLAGS", "")  # require() may add the CPU flag: restored after the test
    monkeypatch.setitem(sys.modules, "jax", None)  # import jax -> ImportError, as without the extra
    with pytest.raises(ConfigError, match=r'pip install -e "\.\[mjx\]"'):
        backend.require()


@needs_mjx
def test_xla_cpu_fusion_emitters_are_turned_off_only_where_jaxlib_has_the_slow_default(monkeypatch):
    """jaxlib 0.7's XLA:CPU fusion emitters run MJX 100-300x slower (benchmarks/bench_mjx.py); the flag goes
    into XLA_FLAGS for those versions only (an unknown flag aborts XLA), and a user's own choice stays."""
    from importlib.metadata import version

    from bench.sims import mjx as backend

    mine = f"--xla_dump_hlo_as_text=false {backend.DEVICES_FLAG}=3"  # the user's device count stays
    monkeypatch.setenv("XLA_FLAGS", mine)
    jaxlib = tuple(int(p) for p in version("jaxlib").split(".")[:2])
    slow = backend.CPU_FLAG_JAXLIB[0] <= jaxlib < backend.CPU_FLAG_JAXLIB[1]
    assert backend.xla_cpu_flags() == (backend.CPU_FLAG if slow else None)
    want = mine + (f" {backend.CPU_FLAG}" if slow else "")
    assert os.environ["XLA_FLAGS"] == want
    assert backend.xla_cpu_flags() is None and os.environ["XLA_FLAGS"] == want  # once only
    monkeypatch.setenv("XLA_FLAGS", f"--xla_cpu_use_fusion_emitters=true {backend.DEVICES_FLAG}=1")
    assert backend.xla_cpu_flags() is None
    assert os.environ["XLA_FLAGS"] == f"--xla_cpu_use_fusion_emitters=true {backend.DEVICES_FLAG}=1"


def test_one_xla_host_device_per_usable_core(monkeypatch):
    """A compiled call keeps one core busy; batched MJX paths split their worlds across one host device per core
    (bench.sims.mjx_lift.control.Compiled.step), so require() asks XLA for as many as this process may use."""
    from bench.sims import mjx as backend

    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=false")
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2}, raising=False)
    backend.xla_cpu_flags()
    assert os.environ["XLA_FLAGS"] == f"--xla_cpu_use_fusion_emitters=false {backend.DEVICES_FLAG}=3"
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_use_fusion_emitters=false")
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0}, raising=False)
    backend.xla_cpu_flags()
    assert os.environ["XLA_FLAGS"] == "--xla_cpu_use_fusion_emitters=false"  # one core: XLA's default


# --- batched simulation equals the CPU path -------------------------------------------------------------
@needs_mjx
def test_mjx_simulator_equals_cpu_for_perturbed_variants():
    """Four variants (damping, masses, gravity differ) x 6 segments: MJX and mujoco.rollout agree to 1e-9."""
    from bench.replay.mjx import MjxSimulator
    from bench.replay.sweep import TOLERANCE

    model = mujoco.MjModel.from_xml_path(str(ARM))
    rng = np.random.default_rng(0)
    n, substeps = 60, 2
    model.opt.timestep = 0.005
    rec = Recording(
        fps=100.0,
        qpos=0.3 * rng.standard_normal((n, 3)),
        qvel=0.3 * rng.standard_normal((n, 3)),
        ctrl=2.0 * rng.standard_normal((n, 3)),
        inputs=None,
        offsets=np.array([0, n]),
        train=[Window(0, 0, n)],
        holdout=[],
        qvel_logged=True,
    )
    variants = []
    for d, mass, g in ((1.0, 1.0, 1.0), (0.5, 1.0, 1.0), (2.0, 1.3, 1.0), (1.0, 0.8, 0.5)):
        m = mujoco.MjModel.from_xml_path(str(ARM))
        m.opt.timestep = 0.005
        m.dof_damping[:] *= d
        m.body_mass[1:] *= mass
        m.body_inertia[1:] *= mass
        m.opt.gravity[:] *= g
        mujoco.mj_setConst(m, mujoco.MjData(m))
        variants.append(Variant(m, hold(rec.ctrl, substeps), 0.1 * rng.standard_normal(3)))
    segs = Segments(np.arange(0, 48, 8), 10)
    cpu = Simulator(model, rec, substeps)
    gpu = MjxSimulator(model, rec, substeps)
    try:
        a, b = cpu.run(variants, segs), gpu.run(variants, segs)
    finally:
        cpu.close()
        gpu.close()
    assert a.shape == b.shape == (4, 6, 10, 6)
    assert np.abs(a - b).max() < TOLERANCE * 1e-3
    assert np.abs(a[0] - a[2]).max() > 1e-3  # the variants differ: the comparison is not of one world
    assert gpu.steps == cpu.steps == 4 * 6 * 10 * substeps


def sweep_differences(a: list[dict], b: list[dict], tol: float) -> list[str]:
    """Where two sweeps' records differ: structure and parameters exactly, numbers beyond `tol`."""
    diffs: list[str] = []

    def walk(x: Any, y: Any, path: str) -> None:
        if isinstance(x, dict) and isinstance(y, dict):
            if set(x) != set(y):
                diffs.append(f"{path}: keys {sorted(x)} != {sorted(y)}")
                return
            for key in x:
                walk(x[key], y[key], f"{path}.{key}")
        elif isinstance(x, list) and isinstance(y, list):
            if len(x) != len(y):
                diffs.append(f"{path}: {len(x)} != {len(y)} items")
                return
            for i, (u, v) in enumerate(zip(x, y)):
                walk(u, v, f"{path}[{i}]")
        elif isinstance(x, float) and isinstance(y, float) and ".horizons." in path:
            if abs(x - y) > tol:
                diffs.append(f"{path}: {x!r} vs {y!r} (|diff| {abs(x - y):.3g} > {tol:g})")
        elif x != y:
            diffs.append(f"{path}: {x!r} != {y!r}")

    walk(a, b, "records")
    return diffs


def each_way(tmp_path: Path, key: str, values: tuple[str, ...], written: str, *args: str) -> dict[str, dict]:
    """`bench ARGS KEY=V out=tmp_path/V` once for each V (each asserted to exit 0): the JSON file `written` of each."""
    docs = {}
    for value in values:
        r = bench(*args, f"{key}={value}", f"out={tmp_path / value}")
        assert r.returncode == 0, r.stderr
        docs[value] = json.loads((tmp_path / value / written).read_text())
    return docs


# --- slow: the commands end to end ------------------------------------------------------------------------
@needs_mjx
@pytest.mark.slow
def test_replay_sweep_mjx_records_equal_cpu(case, tmp_path):
    """`bench replay ... perturb.*` gives the same records with backend=mjx as with mujoco (within TOLERANCE)."""
    from bench.replay.sweep import TOLERANCE

    args = [f"logs={case / 'logs'}", f"spec={case / 'spec.yaml'}", "k=10", "worlds=2", "seed=3", "plot=0"]
    sweep = ["perturb.damping=[0.5,2]", "perturb.link_mass=uniform(0.8,1.2)"]
    docs = each_way(tmp_path, "backend", ("mujoco", "mjx"), "replay.json", "replay", *args, *sweep)
    a, b = docs["mujoco"]["sweep"], docs["mjx"]["sweep"]
    assert a["worlds"] == b["worlds"] == 5  # nominal, two damping levels, two draws of the mass range
    assert [r["params"] for r in a["records"]] == [r["params"] for r in b["records"]]
    assert sweep_differences(a["records"], b["records"], TOLERANCE) == []
    assert docs["mjx"]["backend"] == "mjx" and docs["mjx"]["mjx"]["device"]
    assert docs["mujoco"]["horizons"]["k_step"]["rmse"] == pytest.approx(
        docs["mjx"]["horizons"]["k_step"]["rmse"], abs=TOLERANCE
    )


@needs_mjx
@pytest.mark.slow
def test_gradient_calibration_matches_least_squares(case, tmp_path):
    """method=gradient finds the hidden damping like least squares, to the same held-out error."""
    args = [f"spec={case / 'spec.yaml'}", f"logs={case / 'logs'}", "effects=[viscous_damping,coulomb_friction]"]
    methods = ("least_squares", "gradient")
    res = each_way(tmp_path, "method", methods, "calibration.json", "calibrate", *args, "residual=false", "quiet=true")
    ls, gd = res["least_squares"], res["gradient"]
    assert [e["name"] + "@" + e["target"] for e in gd["effects_added"]] == ["viscous_damping@j2"]
    assert [e["name"] for e in ls["effects_added"]] == [e["name"] for e in gd["effects_added"]]
    assert gd["effects_added"][0]["params"]["damping"] == pytest.approx(1.2, rel=0.02)
    e_ls, e_gd = ls["errors"]["final"]["free_run_nrmse"], gd["errors"]["final"]["free_run_nrmse"]
    assert e_gd <= e_ls * 1.05
    assert gd["method"]["name"] == "gradient" and gd["method"]["fits"] >= 2 and gd["method"]["fallbacks"] == 0


@needs_mjx
@pytest.mark.slow
def test_non_finite_gradient_names_window_and_parameter(case, tmp_path):
    """A motor gear of 1e200 makes the simulation overflow: the fit stops naming the window and the parameter,
    exit 2. (A negative damping would do it too, but such bounds are refused before any work.)"""
    spec = tmp_path / "spec.yaml"
    text = (case / "spec.yaml").read_text().replace("arm3_declared.xml", str(case / "arm3_declared.xml"))
    declared = "- name: damping\n  field: dof_damping\n  elements: [j1, j3]\n  bounds: [0.0, 3.0]"
    assert declared in text
    spec.write_text(
        text.replace(
            declared,
            "- name: gear\n  field: actuator_gear\n  column: 0\n  elements: [m1]\n  bounds: [1.0e200, 2.0e200]",
        )
    )
    out = tmp_path / "out"
    r = bench(
        "calibrate",
        f"spec={spec}",
        f"logs={case / 'logs'}",
        f"out={out}",
        "method=gradient",
        "effects=none",
        "quiet=true",
    )
    assert r.returncode == 2, r.stderr
    line = r.stderr.strip().splitlines()[-1]
    assert "gradient turned non-finite in window" in line and "for parameter gear = 1e+200" in line
    assert "method=least_squares" in line
    assert not out.exists()


@needs_mjx
@pytest.mark.slow
@pytest.mark.skipif(
    not (SHARED / "data/real/panda_gaz/trajectory_1.csv").exists(), reason="needs ../shared/data/real/panda_gaz"
)
def test_gradient_fit_on_real_panda_log_reaches_least_squares(tmp_path):
    """The real Panda log (its first 6 s; 100-step windows), torque-driven: the gradient fit's held-out k-step error is within the
    least-squares fit's 95% bootstrap interval (or below it)."""
    sys.path.insert(0, str(REPO))
    from benchmarks.bench_calibrate_gradient import calibrate, panda_case

    spec, logs = panda_case(tmp_path, seconds=6.0)
    ls = calibrate(spec, logs, "least_squares")
    gd = calibrate(spec, logs, "gradient")
    assert gd["kstep"] <= ls["interval"][1], (gd["kstep"], ls["interval"])
    assert gd["kstep"] < 0.9 * calibrate_nominal(spec, logs)


def calibrate_nominal(spec: Path, logs: Path) -> float:
    """Held-out k-step error of the model as given (declared values, no fit)."""
    from bench.calibrate.data import extract  # the calibration's: splits off the held-out share
    from bench.calibrate.fit import Objective
    from bench.calibrate.model import Layout, Plant
    from bench.calibrate.spec import load_spec
    from bench.logs import read_dataset
    from bench.replay.simulate import horizons
    from bench.replay.spec import load_model

    s = load_spec(spec)
    ds = read_dataset(logs)
    model = load_model(s.model)
    rec = extract(s, [e.data for e in ds.episodes], float(ds.fps), nq=model.nq, nv=model.nv, nu=model.nu, seed=0)
    plant = Plant(s, model, rec)

    k = max(1, int(round(s.horizon * rec.fps)))
    train = rec.frames(rec.train)
    scale = np.maximum(np.concatenate([rec.qpos[train], rec.qvel[train]], axis=1).std(axis=0), 1e-9)
    sim = plant.simulator()
    try:
        obj = Objective(sim, Layout(plant, []), horizons(rec, rec.holdout, k), rec, scale, np.arange(14))
        grid = obj.residual_grid(plant.declared_nominal()[None])[0]
    finally:
        sim.close()
    return float((grid**2).reshape(len(grid), -1).mean())
