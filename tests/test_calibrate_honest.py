"""Honest fits in the forward (least-squares) loop: any model loads, bounds and errors that rose are said,
and a log recorded under feedback can be declared so."""

from __future__ import annotations

import json
import re
from pathlib import Path

import mujoco
import numpy as np
import pytest
import yaml

from bench.calibrate import play
from bench.calibrate.generate import write_case
from tests.fixtures import calibrated

EXTRA = (
    '<tendon><fixed name="couple"><joint joint="j1" coef="1"/><joint joint="j3" coef="0.5"/></fixed></tendon>'
    '<equality><joint joint1="j3" joint2="j2" polycoef="0 0 0 0 0" active="false"/></equality>'
    '<keyframe><key name="home" qpos="0.1 0.2 0.3" ctrl="0 0 0"/></keyframe>'
)


def _with_extras(xml: str) -> str:
    """An MJCF as a user brings it: a site, a tendon, an equality constraint and a keyframe."""
    xml = xml.replace("</worldbody>", "</worldbody>" + EXTRA, 1)
    return re.sub(r'(<body name="link3"[^>]*>)', r'\1<site name="tool" pos="0 0 -0.25"/>', xml, count=1)


def calibrate(spec: Path, case: Path, out: Path, effect: str) -> dict:
    """`bench calibrate` of the case's logs under `spec`, searching `effect` alone; its calibration.json."""
    return json.loads(calibrated(case, out, f"effects=[{effect}]", "residual=false", spec=spec).read_text())


def test_play_rebuild_keeps_keyframes_sites_tendons_and_equalities():
    xml = _with_extras((Path(play.__file__).parent / "models" / "arm3.xml").read_text())
    base = mujoco.MjModel.from_xml_string(xml)
    pm = play.build(xml, ((1, "link"), (2, "motor")), base)
    m = pm.model
    assert (m.nkey, m.nsite, m.neq) == (1, 1, 1) and m.ntendon == base.ntendon + 2
    assert np.allclose(m.key_qpos[0], [0.1, 0.2, 0.3, 0.2, 0.3])  # each rotor where its link is
    assert np.allclose(m.key_qvel[0], 0.0)


@pytest.fixture(scope="module")
def backlash_case(tmp_path_factory):
    out = tmp_path_factory.mktemp("backlash")
    write_case(out, "backlash_link", episodes=4, duration=2.0, fps=100.0, seed=0)
    declared = out / "arm3_declared.xml"
    declared.write_text(_with_extras(declared.read_text()))
    return out


def test_a_model_with_a_keyframe_goes_through_the_backlash_candidate(backlash_case, tmp_path):
    out = tmp_path / "cal"
    doc = calibrate(backlash_case / "spec.yaml", backlash_case, out, "backlash_link")
    assert [e["name"] for e in doc["effects_added"]] == ["backlash_link"]


@pytest.fixture(scope="module")
def coulomb_case(tmp_path_factory):
    out = tmp_path_factory.mktemp("coulomb")
    write_case(out, "coulomb_friction", episodes=5, duration=4.0, fps=100.0, seed=0)
    return out


def test_a_parameter_left_on_a_bound_is_said_in_the_report_and_the_last_line(coulomb_case, tmp_path, capsys):
    raw = yaml.safe_load((coulomb_case / "spec.yaml").read_text())
    raw["params"][0]["bounds"] = [0.5, 3.0]  # the true damping is 0.4 / 0.3 / 0.15: the fit ends on the floor
    spec = coulomb_case / "bounded.yaml"
    spec.write_text(yaml.safe_dump(raw))
    out = tmp_path / "cal"
    doc = calibrate(spec, coulomb_case, out, "coulomb_friction")
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert "to check:" in last and "damping[j3]" in last and "at its lower bound" in last
    assert any("at its lower bound" in w for w in doc["warnings"])
    assert "at its lower bound" in (out / "report.md").read_text()


def test_honesty_says_when_another_horizon_rose():
    from bench.calibrate.trace import honesty

    class Lay:
        labels: list[str] = []
        bounds = (np.zeros(0), np.zeros(0))

    errors = {
        "nominal": {"k_step_nrmse": 0.2, "free_run_nrmse": 1.67, "one_step_nrmse": 0.01},
        "declared": {"k_step_nrmse": 0.1, "free_run_nrmse": 1.5, "one_step_nrmse": 0.01},
        "final": {"k_step_nrmse": 0.05, "free_run_nrmse": 2.91, "one_step_nrmse": 0.01},
    }
    said = honesty(Lay(), np.zeros(0), errors)  # type: ignore[arg-type]
    assert len(said) == 1 and "free-run NRMSE rose nominal -> final (1.67 -> 2.91)" in said[0]
    errors["final"]["free_run_nrmse"] = 1.0
    assert honesty(Lay(), np.zeros(0), errors) == []  # type: ignore[arg-type]


def test_a_declared_feedback_loop_keeps_free_runs_bounded_and_the_effect_found(coulomb_case, tmp_path):
    raw = yaml.safe_load((coulomb_case / "spec.yaml").read_text())
    docs = {}
    for name, controller in (("open", None), ("loop", {"kp": [60, 40, 15], "kd": [6, 4, 1.5]})):
        if controller:
            raw["controller"] = controller
        spec = coulomb_case / f"{name}.yaml"
        spec.write_text(yaml.safe_dump(raw))
        docs[name] = calibrate(spec, coulomb_case, tmp_path / name, "coulomb_friction")
    # open loop, the declared model's replay drifts; the loop the log was recorded under holds it near the log
    assert (
        docs["loop"]["errors"]["nominal"]["free_run_nrmse"] < 0.2 * docs["open"]["errors"]["nominal"]["free_run_nrmse"]
    )
    for doc in docs.values():
        assert [(e["name"], e["target"]) for e in doc["effects_added"]] == [("coulomb_friction", "j2")]
    assert docs["loop"]["spec"]["controller"] == {"kp": [60, 40, 15], "kd": [6, 4, 1.5]}
