"""Checkpoint provenance for the gate's verdict: sha256, size, training metadata read from the file generically."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from bench.core.errors import DataError
from bench.core.provenance import POLICY_SPEC_KEY, checkpoint_provenance, safetensors_metadata

REPO = Path(__file__).resolve().parents[1]


def test_committed_checkpoint_carries_its_training_metadata():
    path = REPO / "baselines" / "checkpoints" / "bc_lift_seen40.safetensors"
    prov = checkpoint_provenance(path)
    assert prov["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
    assert prov["size_bytes"] == path.stat().st_size and prov["format"] == "safetensors"
    assert prov["architecture"] == "mlp" and prov["training"]["algorithm"] == "bc" and prov["note"] is None
    assert prov["metadata"] is None  # the header holds only the policy spec


def test_any_safetensors_header_is_read_without_the_tensors(tmp_path: Path):
    from safetensors.numpy import save_file

    spec = {"architecture": "tiny", "meta": {"dataset": "demos_v3", "steps": 1200, "lr": float("nan")}}
    path = tmp_path / "w.safetensors"
    save_file(
        {"w": np.zeros(3, np.float32)},
        str(path),
        metadata={POLICY_SPEC_KEY: json.dumps(spec), "format": "pt", "git": "abc123"},
    )
    assert safetensors_metadata(path) == {POLICY_SPEC_KEY: json.dumps(spec), "format": "pt", "git": "abc123"}
    prov = checkpoint_provenance(path)
    assert prov["training"] == {"dataset": "demos_v3", "steps": 1200, "lr": None}  # NaN never reaches the verdict
    assert prov["metadata"] == {"format": "pt", "git": "abc123"} and prov["architecture"] == "tiny"
    save_file({"w": np.zeros(3, np.float32)}, str(tmp_path / "bare.safetensors"))
    assert safetensors_metadata(tmp_path / "bare.safetensors") is None


def test_weights_only_checkpoint_reads_the_spec_beside_it(tmp_path: Path):
    path = tmp_path / "policy.pt"
    path.write_bytes(b"not read at all")
    path.with_suffix(".json").write_text(json.dumps({"architecture": "mlp", "meta": {"seed": 3}}))
    prov = checkpoint_provenance(path)
    assert prov["training"] == {"seed": 3} and prov["format"] == "pt" and prov["size_bytes"] == 15


@pytest.mark.parametrize(
    "data, match",
    [
        (b"\x01", "header length -1"),
        (b"\xff" * 8 + b"{}", "header length"),
        (b"\x04\x00\x00\x00\x00\x00\x00\x00[1,2", "not valid JSON"),
        (b"\x02\x00\x00\x00\x00\x00\x00\x00[]", "not a JSON object"),
    ],
    ids=["short", "huge-length", "bad-json", "not-object"],
)
def test_corrupt_safetensors_header_is_one_line_and_a_note(tmp_path: Path, data: bytes, match: str):
    path = tmp_path / "bad.safetensors"
    path.write_bytes(data)
    with pytest.raises(DataError, match=match):
        safetensors_metadata(path)
    prov = checkpoint_provenance(path)
    assert match in prov["note"] and prov["sha256"] is not None and prov["training"] is None


def test_file_gone_or_changed_since_the_run_is_noted(tmp_path: Path):
    gone = checkpoint_provenance(tmp_path / "gone.safetensors", "a" * 64)
    assert gone["sha256"] == "a" * 64 and "not found" in gone["note"] and gone["size_bytes"] is None
    path = tmp_path / "x.pt"
    path.write_bytes(b"new bytes")
    changed = checkpoint_provenance(path, "b" * 64)
    assert changed["sha256"] == hashlib.sha256(b"new bytes").hexdigest() and "changed since" in changed["note"]
    trusted = checkpoint_provenance(path, "c" * 64, hash_file=False)  # the caller has just hashed it
    assert trusted["sha256"] == "c" * 64 and trusted["note"] is None


def test_paths_inside_the_checkout_are_recorded_relative_to_it(tmp_path, monkeypatch):
    from bench.core.provenance import ROOT, local, portable, portable_config

    packaged = ROOT / "baselines" / "checkpoints" / "bc_lift_seen40.safetensors"
    assert portable(str(packaged)) == "baselines/checkpoints/bc_lift_seen40.safetensors"
    monkeypatch.chdir(tmp_path)  # wherever a command runs, a recorded path inside the checkout is found
    assert local("baselines/checkpoints/bc_lift_seen40.safetensors") == packaged
    outside = tmp_path / "policy.safetensors"
    assert portable(str(outside)) == str(outside) and portable("runs/x") == "runs/x" and portable(None) is None
    cfg = portable_config({"checkpoint": str(packaged), "out": "runs", "episodes": 3, "env_id": "/not/a/path/key"})
    assert cfg == {
        "checkpoint": "baselines/checkpoints/bc_lift_seen40.safetensors",
        "out": "runs",
        "episodes": 3,
        "env_id": "/not/a/path/key",
    }


def test_a_run_of_the_packaged_policy_records_its_checkpoint_relative_to_the_checkout(tmp_path):
    from bench import api

    p = api.plan(api.RunConfig(policy="bc", robots=["Panda"], episodes=1, out=str(tmp_path), run_id="r"))
    meta, _ = api.start(p, 1)
    stored = json.loads((tmp_path / "r" / "run.json").read_text())
    assert stored == meta
    assert (
        stored["policy"]["checkpoint"]
        == stored["config"]["checkpoint"]
        == ("baselines/checkpoints/bc_lift_seen40.safetensors")
    )
    api.start(p, 1)  # resuming compares the stored (portable) settings with the plan's: the same run
