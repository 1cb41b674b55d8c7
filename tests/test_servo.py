"""Position servos calibrated from their own logs (`method: servo`): the real BAM bench logs (XL330), MuJoCo CPU
against the fit's simulator, and bad input refused through the CLI with one line and nothing written."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from bench.calibrate.servo import calibrate_servo, parse_servo_spec, read_runs
from bench.calibrate.servo.mujoco import simulate_run
from bench.calibrate.servo.sim import make_windows, simulate, substeps_for
from bench.calibrate.servo.verdict import run_verdict, verdict_lines, verdicts
from bench.cli import main

ROOT = Path(__file__).resolve().parents[1]
BAM = ROOT.parent / "shared" / "data" / "real" / "servo_bam"
SPEC = ROOT / "bench" / "calibrate" / "models" / "servo_xl330.yaml"
needs_bam = pytest.mark.skipif(
    not (BAM / "xl330").is_dir(), reason="needs ../shared/data/real/servo_bam (BAM's real servo logs)"
)


@pytest.fixture(scope="module")
def xl330():
    spec = parse_servo_spec(yaml.safe_load(SPEC.read_text()))
    runs = read_runs(BAM / "xl330", spec.columns, units=spec.units, load_scale=spec.load_scale, fps=spec.rate)
    return spec, runs, calibrate_servo(spec, runs)


@needs_bam
def test_xl330_held_out_runs_are_simulated_better_and_the_physics_is_recovered(xl330):
    spec, runs, cal = xl330
    assert all(r.trajectory == "lift_and_drop" for r in runs if r.name in cal.heldout) and len(cal.heldout) == 4
    for name in cal.heldout:
        before, after = cal.errors["declared"][name], cal.errors["final"][name]
        assert after["free_run_rmse"] < 0.5 * before["free_run_rmse"], name
        assert after["free_fall_rmse"] < 0.5 * before["free_fall_rmse"], name  # torque off: new physics
    assert [a["name"] for a in cal.added][:1] == ["load_friction"]
    g = cal.physics["gravity_torque"]
    assert abs(g["relative_error"]) < 0.15, g  # m·g·l from the time series (mass and length never fitted)
    for lab, k in cal.physics["gains"].items():
        assert abs(k["ratio_error"] or 0.0) < 0.15, (lab, k)


@needs_bam
def test_xl330_intervals_hold_the_known_values_and_stay_useful(xl330):
    _, _, cal = xl330
    ph = cal.physics
    assert ph["truths_inside"] == {"inside": 8, "checked": 8}, ph["truths_inside"]  # m·g·l, 4 kp, 3 ratios
    g = ph["gravity_torque"]
    lo, hi = g["interval_data"]
    assert lo <= g["known_mgl"] <= hi and (hi - lo) / g["fitted"] < 0.3  # the data alone, without kt/R's sd
    for lab, k in ph["gains"].items():
        lo, hi = k["interval"]
        assert (hi - lo) / k["fitted"] < 0.12, (lab, k)
        assert k["sd"]["jackknife"] > 0  # the between-run spread is part of it
    kp800 = ph["gains"]["kp=800"]
    assert kp800["sd"]["jackknife"] > kp800["sd"]["jacobian"]  # model error dominates the noise here


@needs_bam
def test_mujoco_cpu_runs_the_same_servo(xl330):
    _, runs, cal = xl330
    p, kp = cal.final.servo()
    run = next(r for r in runs if r.name == cal.heldout[0])
    pk = p.with_(kp=float(kp[cal.labels.index(run.label)]))
    mj = simulate_run(pk, run.goal, run.enable, run.vin, run.q[0], run.dq[0], run.fps, substeps_for(run.fps))
    w = make_windows([run], cal.labels, 0)
    ours = simulate(p.with_(kp=kp[w.label]), w)[0]
    to_log = np.sqrt(np.mean((ours - run.q[1:]) ** 2))
    assert np.sqrt(np.mean((mj - ours) ** 2)) < 0.2 * to_log


@needs_bam
def test_cli_writes_the_calibration(tmp_path, capsys):
    out = tmp_path / "cal"
    assert main(["calibrate", f"spec={SPEC}", f"logs={BAM / 'xl330'}", f"out={out}", "quiet=true"]) == 0
    doc = json.loads((out / "calibration.json").read_text())
    assert doc["schema"] == "bench.calibration.servo/1" and doc["effects_added"]
    report = (out / "report.md").read_text()
    assert report.splitlines()[2].startswith("The calibrated xl330")
    assert "| quantity | unit | ours (95% interval) | BAM m1 |" in report  # BAM's published models beside ours
    assert "Known values inside their 95% intervals: 8 of 8." in report and "s CPU" in report
    assert doc["intervals"]["jackknife_left_out"] and doc["parameters"]["final"]["gravity"]["sd"]["jackknife"] > 0
    console = capsys.readouterr().out
    assert "gravity torque m·g·l" in console
    # the verdict per held-out run and metric: on lift_and_drop kp 100 and 200 the k-step error grows (the torque-on
    # lift) while the free-run and torque-off errors fall; it is said in calibration.json, report.md and the console
    v = doc["verdict"]
    assert (v["runs_better_on_every_metric"], v["runs"]) == (2, 4)
    low = [n for n, r in v["per_run"].items() if doc["errors"]["declared"][n]["label"] in ("kp=100", "kp=200")]
    for n in low:
        assert v["per_run"][n]["verdict"] == "mixed" and v["per_run"][n]["worse_on"] == ["k-step"], v["per_run"][n]
        parts = v["per_run"][n]["k_step_parts"]
        assert not parts["torque-on windows"]["better"], parts  # the lift with the torque on is what got worse
        line = next(x for x in console.splitlines() if x.startswith(f"NOT better on every metric: {n}"))
        assert "k-step" in line and "(worse)" in line and "torque-on windows" in line
        assert f"NOT better on every metric: {n}" in report
    assert "held-out runs predicted better on every metric (free-run, k-step, torque off): 2 of 4" in report
    assert report.count("| mixed: k-step worse |") == 2


def _run(n: int = 40, **meta) -> dict:
    t = np.arange(n) * 0.005
    entries = [
        {
            "timestamp": float(x),
            "position": float(0.1 * np.sin(x)),
            "goal_position": float(0.2 * np.sin(x)),
            "torque_enable": True,
            "load": 10,
            "input_volts": 7.4,
        }
        for x in t
    ]
    return {
        "mass": 0.5,
        "length": 0.1,
        "kp": 100,
        "vin": 7.4,
        "motor": "xl330",
        "trajectory": "sin_sin",
        "entries": entries,
        **meta,
    }


def _backwards(d: dict) -> None:
    d["entries"][5]["timestamp"] = d["entries"][3]["timestamp"]
    d["entries"][6]["timestamp"] = 0.0


def _degrees(d: dict) -> None:
    for e in d["entries"]:
        e["position"] *= 180 / np.pi * 20


def _small_degrees(d: dict) -> None:
    for e in d["entries"]:  # within one turn's range even in degrees (at most 5.7), against a goal in rad
        e["position"] *= 180 / np.pi


def _no_goal(d: dict) -> None:
    for e in d["entries"]:
        del e["goal_position"]


def _kp0(d: dict) -> None:
    d["kp"] = 0


@pytest.mark.parametrize(
    ("edit", "pattern"),
    [
        (_backwards, "not increasing"),
        (_degrees, "looks like degrees"),
        (_small_degrees, "'position' spreads 28.6x more than 'goal_position'"),
        (_no_goal, "goal position"),
        (_kp0, "kp is 0"),
    ],
    ids=["non_monotonic_time", "degrees_declared_rad", "small_degrees_beside_a_goal_in_rad", "goal_missing", "kp_zero"],
)
def test_bad_servo_logs_are_refused_with_one_line_and_nothing_written(tmp_path, capsys, edit, pattern):
    logs = tmp_path / "logs"
    logs.mkdir()
    good, bad = _run(), _run()
    edit(bad)
    (logs / "a.json").write_text(json.dumps(good))
    (logs / "b.json").write_text(json.dumps(bad))
    out = tmp_path / "out"
    code = main(["calibrate", f"spec={SPEC}", f"logs={logs}", f"out={out}", "quiet=true"])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and pattern in err, err
    assert not out.exists()


@needs_bam
def test_sts3250_without_a_saturating_run_reports_its_scale_as_unidentified():
    """No duty logged and sin_time_square (the only run that saturates the PWM) held out: the gain's scale is flat,
    and the scale profile widens the gain's and m·g·l's intervals to hold the known values instead of excluding them."""
    spec = parse_servo_spec(yaml.safe_load((SPEC.parent / "servo_sts3250.yaml").read_text()))
    spec = dataclasses.replace(spec, holdout={"trajectory": "sin_time_square"})
    runs = read_runs(BAM / "sts3250", spec.columns, units=spec.units, load_scale=spec.load_scale, fps=spec.rate)
    cal = calibrate_servo(spec, runs)
    k = cal.physics["gains"]["kp=32"]
    assert k["fitted"] < 8 and k["inside"], k  # fitted far off, and the interval says so
    assert k["interval"][1] > 10 * max(k["interval"][0], k["fitted"] / 10)
    assert cal.physics["gravity_torque"]["inside"]
    assert len(cal.jackknives["final"].alternates) >= 2


def test_sts3250_lift_and_drop_fold_intervals_hold_the_known_values():
    """The fold whose fit lands in the low-gain basin (kp 19.8, m·g·l 0.64 against 32 and 1.33): warm-started
    leave-one-run-out refits stayed in that basin and the intervals excluded both known values. Each refit now starts
    where the estimator would without that run (without sin_time_square the gain collapses), and with 3 runs the
    jackknife's variance has 2 degrees of freedom (t = 4.30, not 1.96)."""
    spec = parse_servo_spec(yaml.safe_load((SPEC.parent / "servo_sts3250.yaml").read_text()))
    runs = read_runs(BAM / "sts3250", spec.columns, units=spec.units, load_scale=spec.load_scale, fps=spec.rate)
    cal = calibrate_servo(spec, runs)
    jk = cal.jackknives["final"]
    kp = jk.replicates[:, cal.final.prob.names.index("kp[kp=32]")]
    assert len(kp) == 3 and kp.min() < 0.7 * cal.final.value("kp[kp=32]"), kp  # a replicate left the basin
    assert jk.quantile({"jacobian": 0.0, "jackknife": 1.0, "torque_scale": 0.0}) == pytest.approx(4.303, abs=1e-3)
    k, g = cal.physics["gains"]["kp=32"], cal.physics["gravity_torque"]
    assert k["inside"] and g["inside"], (k, g)
    assert g["interval_with_torque_scale"][0] >= 0.0 and k["interval"][0] >= 0.0  # cut to the parameter's range


def _errors(free: float, kstep: float, off: float | None, on_k: float, off_k: float | None) -> dict:
    return {
        "free_run_rmse": free,
        "k_step_rmse": kstep,
        "free_fall_rmse": off,
        "k_step_rmse_torque_on": on_k,
        "k_step_rmse_torque_off": off_k,
    }


def test_the_verdict_judges_every_held_out_metric_on_its_own():
    before = _errors(0.20, 0.021, 0.25, 0.015, 0.024)
    mixed = run_verdict(before, _errors(0.05, 0.026, 0.05, 0.032, 0.022))  # free-run 4x better, k-step worse
    assert mixed["verdict"] == "mixed" and mixed["worse_on"] == ["k-step"]
    assert mixed["better_on"] == ["free-run", "torque off"]
    assert not mixed["k_step_parts"]["torque-on windows"]["better"]
    assert mixed["k_step_parts"]["windows with the torque off"]["better"]
    assert run_verdict(before, _errors(0.05, 0.02, 0.05, 0.014, 0.023))["verdict"] == "better"
    worse = run_verdict(_errors(0.025, 0.0158, None, 0.0158, None), _errors(0.048, 0.0165, None, 0.0165, None))
    assert worse["verdict"] == "worse" and "torque off" not in worse["metrics"]  # no torque-off frames: not judged
    errors = {
        "declared": {"a": before, "b": before},
        "final": {"a": _errors(0.05, 0.026, 0.05, 0.032, 0.022), "b": _errors(0.05, 0.02, 0.05, 0.014, 0.023)},
    }
    assert verdicts(errors, ["a", "b"])["runs_better_on_every_metric"] == 1
    lines = verdict_lines(errors, ["a", "b"], {"a": "lift_and_drop, kp=100", "b": "lift_and_drop, kp=800"})
    assert lines[0].endswith("1 of 2") and len(lines) == 2
    assert lines[1] == (
        "NOT better on every metric: a (lift_and_drop, kp=100): k-step 0.0210 -> 0.0260 rad (worse): torque-on "
        "windows 0.0150 -> 0.0320, windows with the torque off 0.0240 -> 0.0220; better on free-run, torque off"
    )
