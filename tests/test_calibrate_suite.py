"""Suite-level calibration: a suite's robot fitted from `bench run record=` logs in its own scene, and
the result carried into runs (`calibration=`), refused for another suite, robot or model."""

import json
import re
from pathlib import Path

import numpy as np
import pytest

from bench.cli import main
from tests.fixtures import recorded

DAMPING = 5.0  # the "real" Panda: every joint damped 5x (perturb.damping)


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """Scripted Panda Lift, recorded nominal and with 5x joint damping: 3 + 3 episodes x 40 frames (~20 s)."""
    tmp = tmp_path_factory.mktemp("suitecal")
    keys = ["robots=[Panda]", "episodes=3", "horizon=40", "workers=2", "policy=scripted"]
    return recorded(tmp, *keys, f"perturb.damping=[{DAMPING:g}]")


@pytest.fixture(scope="module")
def calibrated(logs, tmp_path_factory):
    out = tmp_path_factory.mktemp("cal") / "out"
    assert (
        main(
            [
                "calibrate",
                "suite=held_out_robots",
                "robot=Panda",
                f"logs={logs}",
                f"out={out}",
                f"condition=damping={DAMPING:g}",
                "quiet=true",
                "residual=false",
            ]
        )
        == 0
    )
    return out / "calibration.json"


def test_suite_calibration_recovers_the_real_robot(calibrated):
    doc = json.loads(calibrated.read_text())
    assert doc["suite"]["name"] == "held_out_robots" and doc["suite"]["robot"] == "Panda"
    assert doc["suite"]["condition"] == f"damping={DAMPING:g}" and len(doc["suite"]["episodes"]) == 3
    damping = doc["declared"]["damping_scale"]
    assert damping["value"] == pytest.approx(DAMPING, rel=0.1)  # measured: 4.997 on 4 x 60 frames
    lo, hi = damping["interval"]
    assert lo <= damping["value"] <= hi
    assert doc["declared"]["armature_scale"]["value"] == pytest.approx(1.0, rel=0.1)
    assert doc["errors"]["final"]["free_run_nrmse"] < 0.5 * doc["errors"]["nominal"]["free_run_nrmse"]
    apply = doc["apply"]
    assert apply["robot"] == "Panda" and apply["joints"] == [f"robot0_joint{i}" for i in range(1, 8)]
    by = {(e["field"], e["element"]): e for e in apply["edits"]}
    for i in range(1, 8):
        e = by[("dof_damping", f"robot0_joint{i}")]
        assert e["value"] == pytest.approx(e["nominal"] * damping["value"])
    assert all(
        e["field"] in ("dof_damping", "dof_armature", "dof_frictionloss", "body_mass", "actuator_gainprm")
        for e in apply["edits"]
    )


def one_episode(out: Path, calibration: Path):
    """A run of one 5-step scripted Panda episode (run id c in `out`) with the calibration in `calibration`."""
    from bench import api

    return api.RunConfig(
        robots=["Panda"],
        policy="scripted",
        episodes=1,
        horizon=5,
        workers=1,
        run_id="c",
        out=str(out),
        calibration=str(calibration),
    )


def test_run_with_the_calibration_uses_the_calibrated_model(calibrated, tmp_path):
    from bench import api
    from bench.board.leaderboard import entry_from_summary

    cfg = one_episode(tmp_path, calibrated.parent)
    p = api.plan(cfg)
    worker = api.worker(p)
    try:
        env, _ = worker.built(p.jobs[0])
        edits = json.loads(calibrated.read_text())["apply"]["edits"]
        damping = {e["element"]: e["value"] for e in edits if e["field"] == "dof_damping"}
        model = env.mujoco.model
        assert np.allclose(model.dof_damping[:7], [damping[f"robot0_joint{i}"] for i in range(1, 8)])
    finally:
        worker.close()
    result = api.run(cfg)
    prov = json.loads((result.run_dir / "run.json").read_text())["provenance"]["calibration"]
    assert prov["robot"] == "Panda" and len(prov["sha256"]) == 64
    assert result.summary["config"]["calibration"] == str(calibrated.parent)
    entry = entry_from_summary(result.summary, "x")
    assert entry["selection"]["calibration"] == f"Panda:{prov['sha256'][:12]}"  # apart from nominal runs


def test_resume_refuses_a_calibration_that_changed_under_the_same_path(calibrated, tmp_path):
    """A re-fitted calibration at the same path is another robot: a resumed run never mixes the two."""
    import shutil

    from bench import api
    from bench.core.errors import ConfigError

    cal = tmp_path / "cal"
    shutil.copytree(calibrated.parent, cal)
    cfg = one_episode(tmp_path / "runs", cal)
    api.run(cfg)
    assert api.run(cfg).resumed == 1  # the same calibration resumes
    doc = json.loads((cal / "calibration.json").read_text())
    for e in doc["apply"]["edits"]:
        if e["field"] == "dof_damping":
            e["value"] *= 1.5
    (cal / "calibration.json").write_text(json.dumps(doc))
    with pytest.raises(ConfigError, match=r"recorded with calibration sha256 [0-9a-f]{12} \(now [0-9a-f]{12}\)"):
        api.run(cfg)


def _tampered(calibrated, tmp_path, **change):
    doc = json.loads(calibrated.read_text())
    for key, value in change.items():
        section, field = key.split("__")
        doc[section][field] = value
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(doc))
    return path


BAD_RUNS = [
    (lambda c, t: ["robots=[Sawyer]", f"calibration={c}"], r"is for robot 'Panda', which no selected cell has"),
    (lambda c, t: ["suite=held_out_scenes", f"calibration={c}"], r"fitted for suite 'held_out_robots'"),
    (
        lambda c, t: ["robots=[Panda]", f"calibration={_tampered(c, t, apply__model_hash='0' * 64)}"],
        r"fitted on another model of robot 'Panda' \(model fingerprint 000000000000",
    ),
    (lambda c, t: ["robots=[Panda]", f"calibration={t / 'none.json'}"], r"calibration=.*no such file"),
]


@pytest.mark.parametrize("make, pattern", BAD_RUNS, ids=["other-robot", "other-suite", "other-model", "missing"])
def test_run_refuses_a_calibration_that_does_not_fit(calibrated, tmp_path, capsys, make, pattern):
    code = main(
        [
            "run",
            "policy=scripted",
            "episodes=1",
            "horizon=5",
            "workers=1",
            "run_id=x",
            f"out={tmp_path / 'runs'}",
            *make(calibrated, tmp_path),
        ]
    )
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and re.search(pattern, err), err
    assert not (tmp_path / "runs" / "x").exists()


BAD_CALIBRATIONS = [
    (
        ["suite=held_out_robots", "robot=UR5e"],
        r"robot='UR5e': no episode of .* was recorded with it; robots in the "
        r"log: Panda",
    ),
    (
        ["suite=held_out_robots", "robot=Panda", "condition=damping=9"],
        r"condition='damping=9': no episode .*; conditions: damping=5, nominal",
    ),
    (["suite=held_out_robotz", "robot=Panda"], r"held_out_robotz"),
]


@pytest.mark.parametrize("argv, pattern", BAD_CALIBRATIONS, ids=["robot-not-logged", "condition", "suite"])
def test_suite_calibration_bad_input(logs, tmp_path, capsys, argv, pattern):
    code = main(["calibrate", *argv, f"logs={logs}", f"out={tmp_path / 'out'}"])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1 and re.search(pattern, err), err
    assert not (tmp_path / "out").exists()


def test_card_counts_episodes_that_start_where_the_evaluation_starts(logs, capsys):
    """The log was recorded with run seed 0, so its episodes start from the evaluation's first states."""
    assert main(["logs", "card", str(logs), "suite=held_out_robots", "episodes=3", "seed=0"]) == 0
    assert re.search(r"c\s+1\.000", capsys.readouterr().out)  # 3 seeds x (nominal, damped): all six overlap
    assert main(["logs", "card", str(logs), "suite=held_out_robots", "episodes=3", "seed=1"]) == 0
    assert re.search(r"c\s+0\.000", capsys.readouterr().out)  # another evaluation seed: no overlap


def test_rank_puts_the_undamped_episodes_first_under_the_damped_calibration(logs, calibrated):
    from bench.calibrate.rank import rank
    from bench.logs import read_dataset

    cond = {ep.index: ep.meta["condition"] for ep in read_dataset(logs).episodes}
    doc = rank(calibrated, logs)
    order = [cond[r["episode"]] for r in doc["episodes"]]
    assert order == ["nominal"] * 3 + [f"damping={DAMPING:g}"] * 3, order
