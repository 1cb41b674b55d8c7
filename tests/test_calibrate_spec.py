"""Calibration spec: a good spec parses; each kind of mistake is a one-line SpecError naming the field, exit 2."""

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from bench.calibrate.data import extract
from bench.calibrate.generate import declared_files, simulate_arm, spec_dict
from bench.calibrate.model import Plant
from bench.calibrate.spec import load_spec, parse_spec
from bench.core.errors import SpecError
from bench.replay.spec import load_model


@pytest.fixture(scope="module")
def case(tmp_path_factory) -> Path:
    """Declared arm model + spec, and two short generated episodes."""
    return declared_files(tmp_path_factory.mktemp("spec"), None)


@pytest.fixture(scope="module")
def episodes():
    eps, _ = simulate_arm(None, episodes=2, duration=0.5, seed=0)
    return eps


def _spec(case: Path, **changes) -> dict:
    raw = spec_dict(None)
    raw.update(changes)
    return raw


def _resolve(case: Path, raw: dict, episodes):
    spec = parse_spec(raw, base_dir=case.parent)
    model = load_model(spec.model)
    rec = extract(spec, episodes, 100.0, nq=model.nq, nv=model.nv, nu=model.nu)
    return Plant(spec, model, rec)


def test_good_spec_yaml_and_json_agree(case, tmp_path, episodes):
    from_yaml = load_spec(case)
    raw = yaml.safe_load(case.read_text())
    (case.parent / "spec.json").write_text(json.dumps(raw))
    from_json = load_spec(case.parent / "spec.json")
    assert from_yaml.model == from_json.model == (case.parent / "arm3_declared.xml").resolve()
    assert from_yaml.signals == from_json.signals
    assert [s.label for s in _resolve(case, raw, episodes).slots] == ["damping[j1]", "damping[j2]", "damping[j3]"]
    assert from_yaml.effects is None and from_yaml.holdout == 0.3


BAD = [
    ({"modle": "x.xml"}, r"unknown spec field 'modle'.*Did you mean 'model'"),
    (
        {"params": [{"name": "d", "field": "dof_damping", "elements": ["j1"], "bounds": [0, 1], "bound": 2}]},
        r"unknown spec field 'params\[0\].bound'",
    ),
    (
        {"params": [{"name": "d", "field": "dof_damping", "elements": ["j9"], "bounds": [0, 1]}]},
        r"'params\[0\].elements': 'j9' is not a joint of arm3_declared.xml",
    ),
    (
        {"params": [{"name": "d", "field": "dof_dampin", "elements": ["j1"], "bounds": [0, 1]}]},
        r"'params\[0\].field': 'dof_dampin' is not an MjModel field.*Did you mean 'dof_damping'",
    ),
    (
        {"params": [{"name": "d", "field": "dof_damping", "elements": ["j1"], "bounds": [1, 0]}]},
        r"'params\[0\].bounds' must have low < high",
    ),
    (
        {"params": [{"name": "m", "field": "body_mass", "elements": ["link9"], "bounds": [0, 1]}]},
        r"'link9' is not a body",
    ),
    (
        {"params": [{"name": "m", "field": "body_mass", "elements": ["link1"], "bounds": [-5, -1]}]},
        r"'params\[0\].bounds': \[-5.0, -1.0\] lets body_mass go negative, which a mass cannot; valid: bounds "
        r"within \[0, inf\)",
    ),
    (
        {"params": [{"name": "d", "field": "dof_damping", "elements": ["j1"], "bounds": [-0.5, 2], "scale": True}]},
        r"'params\[0\].bounds': \[-0.5, 2.0\] lets the factor on dof_damping go negative, which a damping cannot",
    ),
    (
        {"effects": [{"name": "torque_saturation", "bounds": [0, 1.5]}]},
        r"'effects\[0\].bounds': \[0.0, 1.5\] lets torque_saturation's clipped_share go above 1, which a share "
        r"of commands cannot; valid: bounds within \[0, 1\]",
    ),
    (
        {"effects": [{"name": "coulomb_friction", "bounds": [-1, 1]}]},
        r"'effects\[0\].bounds': \[-1.0, 1.0\] lets coulomb_friction's friction go negative",
    ),
    ({"effects": ["coulomb_fricton"]}, r"unknown effect 'coulomb_fricton'.*Did you mean 'coulomb_friction'"),
    ({"holdout": 2}, r"spec field 'holdout' must be a number in"),
    (
        {"signals": {"qpos": {"column": "observation.state", "index": [0, 1, 2]}}},
        r"spec field 'signals.ctrl' is required",
    ),
    (
        {
            "signals": {
                "qpos": {"column": "observation.state", "index": [0, 1, 7]},
                "ctrl": {"column": "action", "index": [0, 1, 2]},
            }
        },
        r"'signals.qpos.index': index 7 is out of range for column 'observation.state' of width 6",
    ),
    (
        {
            "signals": {
                "qpos": {"column": "observation.stat", "index": [0, 1, 2]},
                "ctrl": {"column": "action", "index": [0, 1, 2]},
            }
        },
        r"'signals.qpos.column': column 'observation.stat' is not in the log",
    ),
    (
        {
            "signals": {
                "qpos": {"column": "observation.state", "index": [0, 1]},
                "ctrl": {"column": "action", "index": [0, 1, 2]},
            }
        },
        r"'signals.qpos.index' lists 2 columns; the model has nq=3",
    ),
]


@pytest.mark.parametrize(
    "changes, pattern",
    BAD,
    ids=[
        "unknown-field",
        "unknown-param-key",
        "element-not-in-model",
        "not-a-field",
        "bad-bounds",
        "unknown-body",
        "negative-mass",
        "negative-damping-factor",
        "share-above-one",
        "negative-friction",
        "unknown-effect",
        "holdout-range",
        "missing-ctrl",
        "index-out-of-range",
        "missing-column",
        "width-vs-model",
    ],
)
def test_malformed_spec_is_one_line_spec_error(case, episodes, changes, pattern):
    raw = _spec(case, **changes)
    with pytest.raises(SpecError, match=pattern) as info:
        _resolve(case, raw, episodes)
    assert "\n" not in str(info.value)


def test_missing_model_file(tmp_path):
    with pytest.raises(SpecError, match=r"spec field 'model': MJCF file .* does not exist"):
        parse_spec({"model": "nope.xml", "signals": {}}, base_dir=tmp_path)


@pytest.mark.parametrize(
    "changes, pattern", [BAD[0], BAD[2], BAD[9]], ids=["unknown-field", "bad-element", "index-out-of-range"]
)
def test_cli_malformed_spec_exit_2_one_line(tmp_path, capsys, changes, pattern):
    from bench.calibrate.generate import write_case
    from bench.cli import main

    case = write_case(tmp_path / "case", None, episodes=2, duration=0.5)
    raw = _spec(case, **changes)
    (case / "bad.yaml").write_text(yaml.safe_dump(raw))
    code = main(["calibrate", f"spec={case / 'bad.yaml'}", f"logs={case / 'logs'}", f"out={tmp_path / 'out'}"])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert err.startswith("error: ")
    assert not (tmp_path / "out").exists()
    import re

    assert re.search(pattern, err), err


def test_cli_unknown_key_suggests(capsys):
    from bench.cli import main

    assert main(["calibrate", "spec=a.yaml", "logz=b", "out=c"]) == 2
    assert "Did you mean 'logs'" in capsys.readouterr().err


def test_substeps_default_from_timestep_and_fps(case, episodes):
    raw = _spec(case)
    raw.pop("substeps")
    plant = _resolve(case, raw, episodes)
    assert plant.substeps == 5  # arm3.xml: 2 ms timestep, 100 Hz logs
    assert np.isclose(plant.model.opt.timestep, 0.002)
