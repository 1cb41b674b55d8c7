"""The Real2Sim loop on data whose answer is known, on null data, end to end, and on real measured logs.

Each synthetic case: a 3-joint arm under PD tracking with ONE hidden effect, 5 episodes x 4 s at
100 Hz with sensor noise. The loop must name the effect and its target (and nothing else), recover
its parameters within 25% and cut the held-out free-run NRMSE of the declared fit by at least half.
Some families look alike and every case runs with all of them in the library: a spring with its
own rest position vs a constant offset (bias) or a gravity load (payload mass, which pulls towards
the hanging pose); backlash (position play) vs Coulomb friction or a force dead band.
"""

import json
import math

import numpy as np
import pytest

from bench.calibrate.effects import EFFECTS
from bench.calibrate.generate import MODELS, declared_files, simulate_arm
from bench.calibrate.spec import load_spec
from bench.calibrate.trace import calibrate_episodes
from tests.fixtures import calibrated

FAST = {"coulomb_friction", "actuator_delay", "payload_mass", "joint_spring", "backlash_motor"}  # the rest: -m slow
# more cases of the families that compete: (effect, target, true parameters)
COMPETING = {
    "spring-other-joint-and-side": ("joint_spring", "j1", {"stiffness": 6.0, "reference": -0.3}),
    "gravity-load-not-a-spring": ("payload_mass", "link2", {"mass": 0.6}),
}


def _calibrate(tmp_path, effect, target=None, params=None):
    episodes, truth = simulate_arm(effect, episodes=5, duration=4.0, seed=0, target=target, params=params)
    spec = load_spec(declared_files(tmp_path, effect, target))
    return calibrate_episodes(spec, episodes, 100.0, seed=0), truth


CASES = [pytest.param(e, None, None, marks=() if e in FAST else pytest.mark.slow, id=e) for e in EFFECTS] + [
    pytest.param(*case, marks=pytest.mark.slow, id=name) for name, case in COMPETING.items()
]


@pytest.mark.parametrize("effect, target, true_params", CASES)
def test_loop_finds_the_hidden_effect(tmp_path, effect, target, true_params):
    cal, truth = _calibrate(tmp_path, effect, target, true_params)
    found = [(a["name"], a["target"]) for a in cal.added]
    assert found == [(truth.effect, truth.target)], f"added {found}, hidden {truth.effect}@{truth.target}"
    params = cal.added[0]["params"]
    for key, true in truth.params.items():
        assert abs(params[key] - true) <= 0.25 * abs(true), f"{key}: found {params[key]:.4g}, true {true:.4g}"
        lo, hi = cal.added[0]["interval"][key]
        assert lo <= params[key] <= hi
    before, after = cal.errors["declared"]["free_run_nrmse"], cal.errors["final"]["free_run_nrmse"]
    assert after <= 0.5 * before, f"held-out free-run NRMSE {before:.4g} -> {after:.4g}"


def test_null_data_adds_nothing(tmp_path):
    cal, _ = _calibrate(tmp_path, None)
    assert cal.added == []
    assert cal.rejected, "candidates are still scored and reported"
    assert cal.errors["final"]["free_run_nrmse"] == cal.errors["declared"]["free_run_nrmse"]


def _no_nan(text: str) -> dict:
    def bad(token):
        raise AssertionError(f"{token} in calibration.json")

    return json.loads(text, parse_constant=bad)


def test_cli_end_to_end_report(tmp_path, capsys):
    from bench.calibrate.generate import write_case

    case = write_case(tmp_path / "case", "bias", episodes=4, duration=3.0, seed=1)
    doc = _no_nan(calibrated(case, tmp_path / "out").read_text())
    assert "effects added: bias@j2" in capsys.readouterr().out
    assert doc["schema"] == "bench.calibration/1"
    assert set(doc["errors"]) == {"nominal", "declared", "final"}
    for entry in doc["errors"].values():
        for key in ("one_step_nrmse", "k_step_nrmse", "free_run_nrmse", "free_run_rmse", "r2"):
            assert isinstance(entry[key], float) and math.isfinite(entry[key])
    assert set(doc["declared"]) == {"damping[j1]", "damping[j2]", "damping[j3]"}
    (added,) = doc["effects_added"]
    assert {"name", "target", "params", "interval"} <= set(added)
    assert all("score" in e for e in doc["effects_rejected"])
    assert doc["wall_seconds"] > 0
    report = (tmp_path / "out" / "report.md").read_text()
    for png in ("freerun.png", "residual.png", "scores.png"):
        assert (tmp_path / "out" / png).stat().st_size > 10_000
        assert f"({png})" in report


def test_effects_override_none_keeps_declared_fit(tmp_path):
    episodes, _ = simulate_arm("bias", episodes=3, duration=2.0, seed=0)
    cal = calibrate_episodes(load_spec(declared_files(tmp_path, "bias")), episodes, 100.0, effects=())
    assert cal.added == [] and cal.rounds == []
    assert np.all(np.isfinite(cal.declared_fit.sd))


def test_pendulum_smoke(shared_dir, tmp_path):
    """Real measured pendulum logs (noisy torque): the loop runs and reports; no precision claim."""
    from bench.calibrate.report import write_report
    from bench.logs import import_csv

    ds = import_csv(
        shared_dir / "data/real/simple_pendulum/data_measured.csv",
        time="time",
        state=["position", "velocity"],
        action=["torque"],
    )
    spec = load_spec(MODELS / "pendulum.yaml")
    cal = calibrate_episodes(spec, [e.data for e in ds.episodes], ds.fps)
    doc = _no_nan(write_report(cal, tmp_path).read_text())
    assert doc["data"]["holdout"][0]["start"] > 0  # one run: held out in time
    assert 0.05 <= doc["declared"]["mass"]["value"] <= 5


@pytest.mark.slow
def test_emps_real_data(shared_dir, tmp_path):
    """EMPS: a moving mass with viscous damping misses dry friction (asymmetric: Coulomb + offset)."""
    from bench.logs import import_mat

    ds = import_mat(shared_dir / "data/real/emps/DATA_EMPS.mat", {"observation.state": ["qm"], "action": ["vir"]})
    cal = calibrate_episodes(load_spec(MODELS / "emps.yaml"), [e.data for e in ds.episodes], ds.fps)
    names = {a["name"] for a in cal.added}
    assert names & {"coulomb_friction", "asymmetric_friction", "stribeck_friction"}, names
    before, after = cal.errors["declared"]["free_run_rmse"], cal.errors["final"]["free_run_rmse"]
    assert after < 0.5 * before
    mass = cal.final_fit.x[cal.final_fit.labels.index("mass")]
    assert 80 < mass < 110  # the dataset's own identification: 95.1 kg
