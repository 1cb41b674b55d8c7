"""`bench calibrate design`: an excitation within every limit that identifies the spec's parameters, better
conditioned than a random one and than a one-path log (which it warns about); bad input; determinism."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from bench.calibrate.arm.design import limits_of, run_design
from bench.calibrate.arm.dynamics import Dynamics
from bench.calibrate.arm.generate import JOINTS, MODEL, spec_dict
from bench.calibrate.arm.idim import FRICTION_V
from bench.calibrate.arm.model import build
from bench.calibrate.arm.spec import load_arm_spec
from bench.cli import main
from bench.logs import from_arrays, write_dataset

LIMITS = ["velocity=2", "torque=[60,60,30,10,10,5]"]  # the synthetic arm's motors have no ctrlrange


@pytest.fixture(scope="module")
def arm(tmp_path_factory) -> Path:
    """The synthetic six-joint arm and its payload spec (bench.calibrate.arm.generate)."""
    case = tmp_path_factory.mktemp("arm6")
    (case / "arm6.xml").write_text(MODEL.read_text())
    (case / "spec.yaml").write_text(yaml.safe_dump(spec_dict("payload"), sort_keys=False))
    return case


def _design(arm: Path, out: Path, *extra: str) -> int:
    return main(["calibrate", "design", f"spec={arm / 'spec.yaml'}", f"out={out}", *LIMITS, "quiet=true", *extra])


@pytest.fixture(scope="module")
def designed(arm, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("designed") / "design"
    assert _design(arm, out) == 0
    return out


def _torque(arm: Path, q: np.ndarray, dq: np.ndarray, ddq: np.ndarray) -> np.ndarray:
    """The declared arm's rigid-body torque plus its declared friction (what its drives must deliver)."""
    am = build(load_arm_spec(arm / "spec.yaml"))
    m, d = am.model, am.dadr
    tau = Dynamics(m, am.qadr, d, am.qpos0).torques(q, dq, ddq)
    return tau + m.dof_damping[d] * dq + m.dof_frictionloss[d] * np.tanh(dq / FRICTION_V)


def test_the_design_meets_every_limit_on_a_fine_grid(designed, arm):
    doc = json.loads((designed / "design.json").read_text())
    tr, lim = doc["trajectory"], doc["limits"]
    q0, a, b, period = np.array(tr["q0"]), np.array(tr["a"]), np.array(tr["b"]), tr["period_s"]
    t = np.linspace(0.0, period, 20_001)  # 0.5 ms, both ends
    wl = 2 * np.pi / period * np.arange(1, a.shape[1] + 1)
    s, c = np.sin(np.outer(t, wl)), np.cos(np.outer(t, wl))
    q = q0 + s @ (a / wl).T - c @ (b / wl).T  # the stated form
    dq, ddq = c @ a.T + s @ b.T, -s @ (a * wl).T + c @ (b * wl).T
    lo, hi = np.array(lim["position"]["used"]).T
    assert np.all(q >= lo) and np.all(q <= hi)
    assert np.all(np.abs(dq) <= np.array(lim["velocity"]))
    assert np.all(np.abs(_torque(arm, q, dq, ddq)) <= np.array(lim["torque"]))
    assert lim["velocity"] == [2.0] * 6 and lim["torque"] == [60, 60, 30, 10, 10, 5]
    rng = np.array(lim["position"]["range"])
    assert np.allclose(lo, rng[:, 0] + 0.05 * (rng[:, 1] - rng[:, 0]))  # 5% of the width kept clear at each end
    assert np.abs(dq[[0, -1]]).max() < 1e-9 and np.abs(ddq[[0, -1]]).max() < 1e-9  # starts and ends at rest
    assert np.abs(q[-1] - q[0]).max() < 1e-9
    csv = np.loadtxt(designed / "trajectory.csv", delimiter=",", skiprows=1)
    header = (designed / "trajectory.csv").read_text().splitlines()[0].split(",")
    assert header == ["t", *[f"{k}{j}" for k in ("q", "dq", "ddq") for j in range(1, 7)]]
    assert csv.shape == (int(period * 1000), 19) and np.allclose(np.diff(csv[:, 0]), 1e-3)
    s, c = np.sin(np.outer(csv[:, 0], wl)), np.cos(np.outer(csv[:, 0], wl))
    assert np.allclose(csv[:, 1:7], q0 + s @ (a / wl).T - c @ (b / wl).T, atol=1e-8)
    assert np.allclose(csv[:, 7:13], c @ a.T + s @ b.T, atol=1e-8)


def test_the_design_is_better_conditioned_than_a_random_start(designed):
    doc = json.loads((designed / "design.json").read_text())
    before, after = doc["before"], doc["after"]
    assert before["of"] == "the first feasible random trajectory"
    assert after["condition_number"] < before["condition_number"]
    assert doc["condition"]["structural_rank"] == doc["condition"]["parameters"] == 22  # friction and payload
    assert after["identified_directions"] == 22 and doc["search"]["seed"] == 0
    assert doc["provenance"]["inputs"]["spec"].endswith("spec.yaml")


def _one_path_log(arm: Path, out: Path) -> Path:
    """Every joint along one direction d: q = q0 + d sin(w t), 8 s at 1 kHz, written as generate.py writes."""
    t = np.arange(8000) / 1000.0
    w, d = 2 * np.pi * 0.25, np.array([0.4, 0.25, -0.35, 0.5, 0.3, -0.45])
    q, dq, ddq = d * np.sin(w * t)[:, None], d * w * np.cos(w * t)[:, None], -d * w * w * np.sin(w * t)[:, None]
    cols = {
        "observation.state": q,
        "observation.velocity": dq,
        "observation.effort": _torque(arm, q, dq, ddq),
        "timestamp": t.astype(np.float32),
        "time_ns": np.round(t * 1e9).astype(np.int64)[:, None],
    }
    names = {k: [f"{j}.{s}" for j in JOINTS] for k, s in zip(list(cols)[:3], ("pos", "vel", "torque"))}
    write_dataset(out, from_arrays([cols], fps=1000.0, task="one path", names=names, robot_type="arm6"))
    return out


def test_a_one_path_log_is_warned_about_and_the_design_fixes_it(designed, arm, tmp_path, capsys):
    logs = _one_path_log(arm, tmp_path / "one_path")
    out = tmp_path / "design"
    assert _design(arm, out, f"logs={logs}") == 0
    captured = capsys.readouterr()
    warning = [line for line in captured.err.splitlines() if line.startswith("warning:")]
    assert len(warning) == 1, captured.err
    assert "the payload's mass apart from its centre of mass" in warning[0] and "the design identifies" in warning[0]
    assert re.search(r"condition number .*: \S+ \(log .*one_path\) -> \S+ \(the design\)", captured.out)
    doc = json.loads((out / "design.json").read_text())
    before, after = doc["before"]["condition_number"], doc["after"]["condition_number"]
    assert before is None or before > 30 * after  # far lower (None: unbounded)
    assert doc["before"]["identified_directions"] < doc["after"]["identified_directions"] == 22
    assert any(g["block"] == "payload" for g in doc["gained"]) and doc["warnings"]
    same = json.loads((designed / "design.json").read_text())["trajectory"]
    assert doc["trajectory"]["a"] == same["a"]  # the log is compared with, not designed from


def _bad(tmp: Path, arm: Path) -> dict[str, tuple[list[str], str]]:
    forward = tmp / "forward.yaml"
    forward.write_text(yaml.safe_dump({"model": str(arm / "arm6.xml"), "joints": list(JOINTS)}))
    spec = f"spec={arm / 'spec.yaml'}"
    return {
        "gravity": (  # at rest, only an exactly upright arm needs under 0.01 N·m at joint2
            [spec, "velocity=2", "torque=[60,0.01,30,10,10,5]"],
            r"^error: key 'torque': joint joint2's limit 0\.01 N·m .* below what gravity alone needs at rest",
        ),
        "too-weak": (  # upright it holds, but nothing moves within 1 N·m
            [spec, "velocity=2", "torque=[60,1,30,10,10,5]"],
            r"^error: key 'torque': none of 16 random trajectories meets the torque limits",
        ),
        "velocity-zero": ([spec, "velocity=0", "torque=60"], r"^error: velocity=0: must be in \(0, 1000\]"),
        "velocity-missing": ([spec, "torque=60"], r"^error: key 'velocity' is required"),
        "velocity-length": ([spec, "velocity=[1,2,3]", "torque=60"], r"^error: key 'velocity' lists 3 limits"),
        "torque-length": ([spec, "velocity=2", "torque=[60,60]"], r"^error: key 'torque' lists 2 limits"),
        "margin": ([spec, *LIMITS, "margin=0.5"], r"^error: key 'margin': 0\.5 .* empty"),
        "harmonics": ([spec, *LIMITS, "harmonics=1"], r"^error: harmonics=1: must be in \[2, 20\]"),
        "period": ([spec, *LIMITS, "period=0.5"], r"^error: period=0\.5: must be in \[1, 120\]"),
        "too-fast": ([spec, *LIMITS, "period=1", "harmonics=20"], r"^error: key 'harmonics': 20 harmonics .*filter_hz"),
        "not-idim": ([f"spec={forward}", *LIMITS], r"^error: spec field 'method': .* needs an arm spec"),
    }


@pytest.mark.parametrize(
    "case",
    [
        "gravity",
        "too-weak",
        "velocity-zero",
        "velocity-missing",
        "velocity-length",
        "torque-length",
        "margin",
        "harmonics",
        "period",
        "too-fast",
        "not-idim",
    ],
)
def test_bad_input_is_one_line_naming_the_field_and_nothing_is_written(arm, tmp_path, capsys, case):
    args, pattern = _bad(tmp_path, arm)[case]
    out = tmp_path / "out"
    code = main(["calibrate", "design", *args, f"out={out}", "quiet=true"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert len(err.strip().splitlines()) == 1 and re.search(pattern, err), err
    assert not out.exists()


def test_an_output_never_overwrites_its_input(arm, capsys):
    code = main(["calibrate", "design", f"spec={arm / 'spec.yaml'}", f"out={arm}", *LIMITS, "quiet=true"])
    err = capsys.readouterr().err
    assert code == 2 and re.search(r"^error: out=.* contains the input spec=", err), err
    assert not (arm / "design.json").exists()


def test_the_same_seed_gives_the_same_design(designed, arm, tmp_path):
    out = tmp_path / "again"
    assert _design(arm, out, "seed=0") == 0
    first, again = (json.loads((d / "design.json").read_text()) for d in (designed, out))
    assert first["trajectory"] == again["trajectory"] and first["after"] == again["after"]
    assert (designed / "trajectory.csv").read_bytes() == (out / "trajectory.csv").read_bytes()
    spec = load_arm_spec(arm / "spec.yaml")
    am = build(spec)
    lim = limits_of(am, 0.05, [2.0], [60, 60, 30, 10, 10, 5])
    other = run_design(spec, am, lim, period=10.0, harmonics=5, seed=1, evaluations=5)  # another seed: another design
    assert not np.allclose(other.fourier.a, np.array(first["trajectory"]["a"]))
