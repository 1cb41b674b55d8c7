"""`bench run calibration=` and the calibration's trust: the forward verdict and the held-out repeat share
recorded in run.json's provenance, a line naming the calibration before the episodes, a warning for a
calibrated model that simulates the held-out data worse than the declared one (or was never checked),
and `strict=true` refusing it before anything is written.

The calibration files are made here: the suite's own Panda fingerprinted (`model_hash`) with its joints
damped 2x, and a `trust` section as `bench calibrate` writes it, edited per case."""

import copy
import json
import re

import pytest

from bench.cli import main

JOINTS = [f"robot0_joint{i}" for i in range(1, 8)]
GOOD_TRUST = {
    "heldout": {
        "placement": "least_repeated",
        "repeat_share": 0.0,
        "nothing_new": False,
        "period_s": 13.34,
        "sentence": "held out: the least repeated stretch of the log, 0% of it repeats fitted states",
    },
    "forward": {
        "criterion": "closed-loop position NRMSE on the held-out data, every horizon and the free run",
        "declared": 0.060,
        "calibrated": 0.0076,
        "simulates_better": True,
        "rose": [],
    },
    "simulates_better": True,
    "estimate": "idim",
    "torque_beats_repeat": True,
    "repeat_baseline_nrmse": 1.35,
}
WORSE_FORWARD = {
    **GOOD_TRUST["forward"],
    "declared": 0.012,
    "calibrated": 0.020,
    "simulates_better": False,
    "rose": ["free run: 0.012 -> 0.02"],
}
RUN = ["run", "robots=[Panda]", "policy=random", "episodes=1", "horizon=5", "workers=1"]


@pytest.fixture(scope="module")
def base():
    """A suite calibration of held_out_robots' Panda (its joints damped 2x) with a good trust section."""
    from bench import api
    from bench.calibrate.apply import model_hash

    suite = api.load_suite("held_out_robots")
    cell = next(c for c in suite.all_cells() if c.robot == "Panda")
    env = suite.make_env(cell, 5)
    try:
        model = env.mujoco.model
        damping = {j: float(model.dof_damping[model.joint(j).dofadr[0]]) for j in JOINTS}
        digest = model_hash(model, JOINTS)
    finally:
        env.close()
    return {
        "schema": "bench.calibration/1",
        "suite": {"name": suite.name, "version": suite.version, "robot": "Panda", "logs": None},
        "trust": GOOD_TRUST,
        "apply": {
            "robot": "Panda",
            "joints": JOINTS,
            "model_hash": digest,
            "edits": [{"field": "dof_damping", "element": j, "nominal": d, "value": 2 * d} for j, d in damping.items()],
        },
    }


def _write(tmp_path, doc, name):
    folder = tmp_path / name
    folder.mkdir()
    (folder / "calibration.json").write_text(json.dumps(doc))
    return folder / "calibration.json"


def _variant(base, tmp_path, case):
    doc = copy.deepcopy(base)
    if case == "worse":
        doc["trust"]["forward"] = copy.deepcopy(WORSE_FORWARD)
        doc["trust"]["simulates_better"] = False
    elif case == "old":
        del doc["trust"]
    elif case == "unchecked":
        doc["trust"]["forward"] = {"simulates_better": None, "why": "the log has no held-out stretch to simulate"}
        doc["trust"]["simulates_better"] = None
    return _write(tmp_path, doc, case)


def _run(tmp_path, cal, *extra):
    return main([*RUN, f"out={tmp_path / 'runs'}", "run_id=r", f"calibration={cal}", *extra])


def _provenance(tmp_path):
    return json.loads((tmp_path / "runs" / "r" / "run.json").read_text())["provenance"]["calibration"]


def test_a_good_calibration_runs_without_warning_and_is_named_and_recorded(base, tmp_path, capsys):
    cal = _variant(base, tmp_path, "good")
    assert _run(tmp_path, cal) == 0
    out, err = capsys.readouterr()
    assert "warning" not in err, err
    line = next(ln for ln in err.splitlines() if ln.startswith("calibration: "))
    assert line == (
        f"calibration: the Panda cells run the calibrated model of {cal} (7 model edits); simulates the held-out "
        "data better than the declared model (closed-loop free run 0.06 -> 0.0076); held-out repeat share 0%"
    )
    assert err.index("calibration: ") < err.index("run r: 1 episode on")  # before the episodes
    prov = _provenance(tmp_path)
    assert prov["robot"] == "Panda" and len(prov["sha256"]) == 64
    assert prov["trust"] == {
        "simulates_better": True,
        "forward": {
            "criterion": GOOD_TRUST["forward"]["criterion"],
            "declared": 0.060,
            "calibrated": 0.0076,
            "rose": [],
        },
        "heldout": {"placement": "least_repeated", "repeat_share": 0.0, "nothing_new": False},
        "estimate": "idim",
        "torque_beats_repeat": True,
    }
    summary = json.loads((tmp_path / "runs" / "r" / "summary.json").read_text())
    assert summary["provenance"]["calibration"]["trust"] == prov["trust"]
    assert "strict" not in summary["config"]  # the default is left out of the stored config
    flat = " ".join(out.split())
    assert f"calibration=Panda:{prov['sha256'][:12]}" in flat and "nominal (calibrated)" in flat  # the table
    assert main(["leaderboard", "validate", str(tmp_path / "runs" / "r" / "summary.json")]) == 0


def test_a_worse_calibration_warns_and_strict_refuses_it(base, tmp_path, capsys):
    cal = _variant(base, tmp_path, "worse")
    warning = (
        f"warning: calibration={cal}: the calibrated Panda simulates the held-out data worse than the declared "
        "model (closed-loop free run: 0.012 -> 0.02); strict=true refuses it"
    )
    assert _run(tmp_path, cal, "strict=true") == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1, err
    assert f"calibration={cal}: the calibrated Panda simulates the held-out data worse" in err
    assert "strict=true" in err and "(closed-loop free run: 0.012 -> 0.02)" in err
    assert not (tmp_path / "runs").exists()  # nothing written, not even the run directory's parent

    assert _run(tmp_path, cal) == 0
    err = capsys.readouterr().err
    assert [ln for ln in err.splitlines() if "warning" in ln] == [warning]
    trust = _provenance(tmp_path)["trust"]
    assert trust["simulates_better"] is False and trust["forward"]["rose"] == ["free run: 0.012 -> 0.02"]
    assert (trust["forward"]["declared"], trust["forward"]["calibrated"]) == (0.012, 0.020)


@pytest.mark.parametrize(
    "case, why",
    [
        ("old", "the file has no trust section"),
        ("unchecked", "the log has no held-out stretch to simulate"),
    ],
)
def test_an_unchecked_calibration_warns_and_strict_refuses_it(base, tmp_path, capsys, case, why):
    cal = _variant(base, tmp_path, case)
    assert _run(tmp_path, cal, "strict=true") == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "was never checked against held-out data" in err, err
    assert why in err and "strict=true" in err
    assert not (tmp_path / "runs").exists()

    assert _run(tmp_path, cal) == 0
    err = capsys.readouterr().err
    warned = [ln for ln in err.splitlines() if "warning" in ln]
    assert len(warned) == 1 and re.fullmatch(
        rf"warning: calibration={re.escape(str(cal))}: the calibrated Panda was never checked against held-out "
        rf"data \(.*{why}.*\); strict=true refuses it",
        warned[0],
    ), warned
    assert re.search(r"^calibration: .*; unchecked \(.*; held-out repeat share (unknown|0%)$", err, re.M), err
    trust = _provenance(tmp_path)["trust"]
    if case == "old":
        assert trust is None
    else:
        assert trust["simulates_better"] is None and trust["forward"]["why"] == why


def test_strict_without_a_calibration_is_refused_and_listed_in_help(tmp_path, capsys):
    assert main([*RUN, f"out={tmp_path / 'runs'}", "strict=true"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "strict=true applies to calibration=" in err, err
    assert not (tmp_path / "runs").exists()
    assert main(["run", "--help"]) == 0
    assert re.search(r"^  strict=false +refuse a calibration= whose model", capsys.readouterr().out, re.M)
