"""An arm calibration's "after" that can be trusted, on synthetic logs whose truth is known: held-out data that
repeat the fit are said to, a one-path excitation gets unbounded intervals instead of confident wrong ones,
a payload's centre of mass outside its declared region is flagged, and bad choices are one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from bench.calibrate.arm.generate import COULOMB, JOINTS, OFFSET, PAYLOAD, VISCOUS, write_arm_case
from bench.calibrate.arm.loop import calibrate_arm
from bench.calibrate.arm.spec import parse_arm_spec
from bench.core.errors import DataError, SpecError
from bench.logs import read_dataset


def _calibrate(case_dir: Path, **changes):
    raw = yaml.safe_load((case_dir / "spec.yaml").read_text())
    raw.update({"bootstrap": 0, "didim": 1, **changes})
    spec = parse_arm_spec(raw, case_dir, case_dir / "spec.yaml")
    ds = read_dataset(case_dir / "logs")
    return calibrate_arm(spec, [e.data for e in ds.episodes], float(ds.fps))


def _truth(com: tuple[float, float, float]) -> dict[str, float]:
    out = {"payload@flange.mass": PAYLOAD["mass"]}
    for ax, c in zip("xyz", com):
        out[f"payload@flange.m{ax}"] = PAYLOAD["mass"] * c
    for i, j in enumerate(JOINTS):
        out[f"{j}.coulomb"], out[f"{j}.viscous"], out[f"{j}.offset"] = COULOMB[i], VISCOUS[i], OFFSET[i]
    return out


def test_a_one_path_excitation_leaves_the_payload_mass_unbounded_and_states_what_is_identified(tmp_path):
    case = write_arm_case(tmp_path, "payload", duration=12.0, excitation="one_path")
    cal = _calibrate(case)
    assert [a["name"] for a in cal.added] == ["payload"]
    p = cal.added[0]
    assert p["mass_interval"] is None and p["com_interval"] is None  # not a confident interval that may exclude 1.2 kg
    assert any("mass and centre of mass are not identified apart" in w for w in cal.warnings)
    status = {q["name"]: q for q in cal.params}
    assert status["payload@flange.mass"]["status"] != "identified" and status["payload@flange.mass"]["interval"] is None
    # every combination the data do identify holds the truth within its interval
    truth = _truth(tuple(PAYLOAD["com"]))
    combos = [c for c in cal.identifiability.combinations if set(c["terms"]) <= set(truth)]
    assert any("payload@flange.mass" in c["terms"] for c in combos)
    for c in combos:
        value = sum(cf * truth[lab] for lab, cf in c["terms"].items())
        lo, hi = c["interval"]
        assert lo - 0.02 * abs(value) - 1e-3 <= value <= hi + 0.02 * abs(value) + 1e-3, c["combination"]


def test_a_periodic_log_holds_nothing_new_and_memory_beats_the_model(tmp_path):
    case = write_arm_case(tmp_path, "payload", duration=20.0, excitation="periodic")
    cal = _calibrate(case)
    h = cal.log.heldout
    assert h.period_s == pytest.approx(10.0, abs=0.05) and h.nothing_new and h.repeat_share > 0.9
    assert any("THE LOG HOLDS NOTHING NEW" in w for w in cal.warnings)
    tq = cal.errors["torque"]
    assert tq["repeat"]["best"] == "period" and not tq["beats_repeat"]  # one period earlier predicts it better
    assert any("does not beat the repeat baseline" in w for w in cal.warnings)
    assert cal.trust["heldout"]["nothing_new"] is True


def test_the_least_repeated_stretch_is_held_out_by_default(tmp_path):
    case = write_arm_case(tmp_path, "none", duration=16.0, excitation="periodic")
    default = _calibrate(case, effects="none", didim=0)
    end = _calibrate(case, effects="none", didim=0, holdout_at="end")
    assert default.log.heldout.repeat_share < 0.5 * end.log.heldout.repeat_share
    assert end.log.heldout.placement == "end" and end.log.heldout.repeat_share > 0.9
    # the plain split would have held out what the fit saw, and the default says so
    assert default.log.heldout.end_share == pytest.approx(end.log.heldout.repeat_share, abs=0.05)


def test_a_payload_whose_centre_of_mass_leaves_the_region_is_flagged_and_found_inside_a_wider_one(tmp_path):
    com = (0.0, 0.0, 0.25)  # a tool reaching 25 cm out; the default region is 15 cm about the flange
    case = write_arm_case(tmp_path, "payload", duration=12.0, payload_com=com)
    narrow = _calibrate(case)
    assert any("outside the declared region" in w and "payload_region" in w for w in narrow.warnings)
    p = narrow.added[0]  # held at the edge: no interval that would exclude the true 1.2 kg with confidence
    assert p["mass_interval"] is None and p["com_interval"] is None
    assert all(q["interval"] is None for q in narrow.params if q["name"].startswith("payload@"))
    wide = _calibrate(case, payload_region={"center": [0, 0, 0.2], "radius": 0.15})
    assert not any("outside the declared region" in w for w in wide.warnings)
    p = wide.added[0]
    assert abs(p["mass"] - PAYLOAD["mass"]) < 0.02 and np.allclose(p["com"], com, atol=5e-3)


@pytest.mark.parametrize(
    "changes, error, pattern",
    [
        ({"payload_region": {"radius": 0}}, SpecError, r"'payload_region\.radius' .*the region is empty"),
        ({"payload_region": {"center": [40, 0, 0], "radius": 0.1}}, SpecError, r"'payload_region'.*outside the model"),
        ({"holdout": [0, 100]}, SpecError, r"'holdout'.*leaves 0 samples to fit"),
        ({"holdout": [50, 60]}, SpecError, r"'holdout'.*holds no sample of the log"),
        ({"period": 30.0}, DataError, r"less than one period of its excitation \(spec field 'period': 30 s\)"),
        ({"holdout_at": "middle"}, SpecError, r"'holdout_at': 'middle'; valid: least_repeated, end, episodes"),
    ],
)
def test_bad_choices_are_one_line_naming_the_field(tmp_path, changes, error, pattern):
    case = write_arm_case(tmp_path, "none", duration=6.0)
    with pytest.raises(error, match=pattern) as info:
        _calibrate(case, **changes)
    assert "\n" not in str(info.value)
