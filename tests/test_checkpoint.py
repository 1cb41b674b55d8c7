"""Checkpoint policies: safetensors/weights-only round trips, spec checks, and `bench run policy=checkpoint`."""

from __future__ import annotations

import json
import pickle
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from baselines.architectures import build
from baselines.checkpoint import load_policy, load_spec, save_checkpoint, spec_path
from bench.core.errors import ConfigError, SpecError
from bench.protocols import STATE, ActionSpec, Feature
from bench.sims.robosuite import ACTION_NAMES
from suites.lift import OBS_FIELDS as OBS_NAMES
from tests.fixtures import each_env


def _spec(**extra) -> dict:
    spec = {"architecture": "mlp", "kwargs": {"hidden": [16, 16]}, "obs_names": OBS_NAMES, "action_names": ACTION_NAMES}
    spec.update(extra)
    return spec


@pytest.fixture
def ckpt(tmp_path: Path) -> Path:
    torch.manual_seed(0)
    model = build("mlp", 18, 7, {"hidden": [16, 16]})
    rng = np.random.default_rng(0)
    norm = {
        "obs": {"mean": rng.normal(size=18), "std": rng.uniform(0.5, 2, 18)},
        "action": {"mean": np.zeros(7), "std": np.full(7, 0.5)},
    }
    return save_checkpoint(tmp_path / "bc" / "policy.safetensors", model, _spec(normalization=norm))


def _env(obs_names=OBS_NAMES, action_names=ACTION_NAMES):
    return SimpleNamespace(obs_spec={STATE: Feature.state(obs_names)}, action_spec=ActionSpec.box(action_names, -1, 1))


def test_round_trip_applies_normalisation_exactly(ckpt: Path):
    spec = json.loads(spec_path(ckpt).read_text())
    policy = load_policy(ckpt)
    model = build("mlp", 18, 7, {"hidden": [16, 16]})
    from safetensors.torch import load_file

    model.load_state_dict(load_file(str(ckpt)))
    obs = np.random.default_rng(1).normal(size=18).astype(np.float32)
    on, an = spec["normalization"]["obs"], spec["normalization"]["action"]
    x = (obs - np.float32(on["mean"])) / np.float32(on["std"])
    want = model(torch.from_numpy(x[None]).float()).detach().numpy()[0] * np.float32(an["std"]) + np.float32(an["mean"])
    np.testing.assert_allclose(policy.act({STATE: obs}), want, rtol=1e-5, atol=1e-6)


def test_actions_are_clipped_to_env_bounds(ckpt: Path):
    policy = load_policy(ckpt, _env())
    acts = np.array([policy.act({STATE: o}) for o in np.random.default_rng(2).normal(scale=100, size=(50, 18))])
    assert acts.min() >= -1 and acts.max() <= 1
    assert np.isclose(np.abs(acts).max(), 1.0)  # large inputs do saturate


def test_weights_only_pt_file_loads(ckpt: Path, tmp_path: Path):
    from safetensors.torch import load_file

    pt = tmp_path / "bc" / "copy.pt"
    torch.save(load_file(str(ckpt)), pt)
    spec_path(pt).write_text(spec_path(ckpt).read_text())
    obs = np.ones(18, np.float32)
    np.testing.assert_array_equal(load_policy(pt).act({STATE: obs}), load_policy(ckpt).act({STATE: obs}))


def test_pickled_object_is_refused(tmp_path: Path):
    path = tmp_path / "evil.pt"
    torch.save({"model": SimpleNamespace(x=1)}, path)  # arbitrary objects need unpickling
    spec_path(path).write_text(json.dumps(_spec()))
    with pytest.raises(SpecError, match="weights_only=True"):
        load_policy(path)


def test_plain_pickle_suffix_refused(tmp_path: Path):
    path = tmp_path / "policy.pkl"
    path.write_bytes(pickle.dumps({"a": 1}))
    with pytest.raises(ConfigError, match=r"unsupported file type '\.pkl'"):
        load_policy(path)


def test_missing_file(tmp_path: Path):
    with pytest.raises(ConfigError, match="no such file"):
        load_policy(tmp_path / "nope.safetensors")


def test_corrupt_safetensors(ckpt: Path):
    ckpt.write_bytes(b"\x00garbage" * 10)
    with pytest.raises(SpecError, match="not a readable safetensors file"):
        load_policy(ckpt)


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda s: s.update(architecture="mlpp"), r"architecture='mlpp' is not registered.*Did you mean 'mlp'"),
        (lambda s: s.update(kwargs={"hiden": [16]}), r"unknown argument 'hiden'.*Did you mean 'hidden'"),
        (lambda s: s.update(kwargs={"hidden": [16, 32]}), "weights do not fit"),
        (lambda s: s.update(obs_dim=19), r"obs_dim=19 but the names give 18"),
        (lambda s: s.update(normalizaton={}), r"unknown field 'normalizaton'"),
        (lambda s: s["normalization"]["obs"].update(std=[0.0] * 18), r"normalization.obs.std must be > 0"),
        (lambda s: s["normalization"]["obs"].update(mean=[0.0] * 3), r"normalization.obs.mean has shape \[3\]"),
        (lambda s: s.pop("obs_names"), "missing field 'obs_names'"),
    ],
    ids=[
        "unknown-arch",
        "unknown-kwarg",
        "shape-mismatch",
        "dim-mismatch",
        "unknown-field",
        "zero-std",
        "bad-mean-shape",
        "no-obs-names",
    ],
)
def test_malformed_spec_is_one_line_spec_error(ckpt: Path, edit, match):
    # drop the embedded copy so the sidecar is what is checked (as for a checkpoint written by other tools)
    from safetensors.torch import load_file, save_file

    save_file(load_file(str(ckpt)), str(ckpt))
    spec = json.loads(spec_path(ckpt).read_text())
    edit(spec)
    spec_path(ckpt).write_text(json.dumps(spec))
    with pytest.raises(SpecError, match=match) as exc:
        load_policy(ckpt)
    assert "\n" not in str(exc.value)


def test_sidecar_that_differs_from_embedded_spec_is_refused(ckpt: Path):
    spec = json.loads(spec_path(ckpt).read_text())
    spec["normalization"]["action"]["std"] = [1.0] * 7
    spec_path(ckpt).write_text(json.dumps(spec))
    with pytest.raises(SpecError, match="field 'normalization' differs from the spec embedded"):
        load_policy(ckpt)


def test_missing_sidecar_falls_back_to_embedded_spec(ckpt: Path):
    obs = np.ones(18, np.float32)
    before = load_policy(ckpt).act({STATE: obs})
    spec_path(ckpt).unlink()
    np.testing.assert_array_equal(load_policy(ckpt).act({STATE: obs}), before)
    with pytest.raises(SpecError, match="not found"):
        load_spec(ckpt, meta={})  # the fallback is the embedded copy, nothing else


def test_no_spec_at_all(tmp_path: Path):
    from safetensors.torch import save_file

    path = tmp_path / "w.safetensors"
    save_file(build("mlp", 18, 7, {"hidden": [4]}).state_dict(), str(path))
    with pytest.raises(SpecError, match=r"policy spec .*w\.json not found"):
        load_policy(path)


def test_obs_names_mismatch_is_config_error(ckpt: Path):
    other = [("joint_pos", 7)] + list(OBS_NAMES[1:])
    with pytest.raises(ConfigError, match=r"obs_names differ from the env's at field 0"):
        load_policy(ckpt, _env(obs_names=other))
    with pytest.raises(ConfigError, match="action_names"):
        load_policy(ckpt, _env(action_names=ACTION_NAMES[::-1]))


def test_policy_checkpoint_needs_its_key_and_others_refuse_it(tmp_path: Path, ckpt: Path):
    res = _bench("run", "policy=checkpoint", "robots=[Panda]", "episodes=1", f"out={tmp_path / 'runs'}", cwd=tmp_path)
    assert res.returncode == 2 and "checkpoint: required" in res.stderr, res.stderr
    res = _bench(
        "run", "policy=scripted", f"checkpoint={ckpt}", "robots=[Panda]", f"out={tmp_path / 'runs'}", cwd=tmp_path
    )
    assert res.returncode == 2 and "unknown key 'checkpoint'" in res.stderr and "policy scripted: (none)" in res.stderr
    assert len(res.stderr.strip().splitlines()) == 1 and not (tmp_path / "runs").exists()


def _bench(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bench", *args], capture_output=True, text=True, cwd=cwd, timeout=300)


def _run_checkpoint(ckpt: Path, tmp_path: Path, *extra: str) -> subprocess.CompletedProcess:
    """`bench run policy=checkpoint` on one Panda episode, run r under tmp_path/runs."""
    keys = ["policy=checkpoint", f"checkpoint={ckpt}", "robots=[Panda]", "episodes=1", "workers=1", "run_id=r"]
    return _bench("run", *keys, *extra, f"out={tmp_path / 'runs'}", cwd=tmp_path)


def test_bench_run_records_checkpoint_sha(ckpt: Path, tmp_path: Path):
    from bench.core.io import sha256_file

    res = _run_checkpoint(ckpt, tmp_path, "horizon=20")
    assert res.returncode == 0, res.stderr[-2000:]
    recs = [json.loads(line) for line in (tmp_path / "runs" / "r" / "episodes.jsonl").read_text().splitlines()]
    assert len(recs) == 1 and recs[0]["error"] is None and recs[0]["length"] == 20
    assert recs[0]["checkpoint_sha256"] == sha256_file(ckpt) and recs[0]["policy"] == "checkpoint"


def test_bench_run_bad_spec_exits_2_and_writes_nothing(ckpt: Path, tmp_path: Path):
    spec = json.loads(spec_path(ckpt).read_text())
    spec["kwargs"] = {"hidden": [8]}
    from safetensors.torch import load_file, save_file

    save_file(load_file(str(ckpt)), str(ckpt))  # no embedded copy
    spec_path(ckpt).write_text(json.dumps(spec))
    res = _run_checkpoint(ckpt, tmp_path)
    assert res.returncode == 2
    assert res.stderr.strip().startswith("error:") and len(res.stderr.strip().splitlines()) == 1
    assert "weights do not fit" in res.stderr
    assert not (tmp_path / "runs").exists()


def test_preflight_checks_declared_names_without_building_an_env(ckpt: Path, tmp_path: Path):
    """held_out_robots declares its action names: the preflight compares a checkpoint with the declaration
    (exit 2 material on a mismatch) and builds no env (seconds saved on every `bench run policy=bc`)."""
    from baselines.checkpoint import CheckpointOptions, CheckpointPlugin
    from suites.held_out_robots import HeldOutRobots

    class NoBuild(HeldOutRobots):
        def make_env(self, cell, horizon):
            raise AssertionError("the preflight built an env")

    suite = NoBuild()
    cells = suite.all_cells()
    CheckpointPlugin().preflight(CheckpointOptions(str(ckpt)), suite, cells, 20)  # names agree: no error
    other = save_checkpoint(
        tmp_path / "rev" / "p.safetensors",
        build("mlp", 18, 7, {"hidden": [16, 16]}),
        _spec(action_names=ACTION_NAMES[::-1]),
    )
    with pytest.raises(ConfigError, match=r"action_names \['gripper'.* differ from the env's \['dx'"):
        CheckpointPlugin().preflight(CheckpointOptions(str(other)), suite, cells, 20)


@pytest.mark.parametrize("name", ["held_out_robots", "held_out_scenes"])
def test_declared_action_names_equal_the_built_env_for_every_cell(name):
    from bench.api import load_suite

    suite = load_suite(name)
    for cell, env in each_env(suite):
        assert list(env.action_spec.names) == list(suite.action_names(cell)), cell.key
