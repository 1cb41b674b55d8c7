"""The example CI workflow in docs/ is valid YAML; its `bench regress` and `bench run` lines are accepted."""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
import yaml

from bench import api
from bench.cli import regress_args
from bench.core.errors import ConfigError

REPO = Path(__file__).resolve().parents[1]
WORKFLOW = REPO / "docs" / "transfer-gate.yml"


def _workflow() -> dict:
    doc = yaml.safe_load(WORKFLOW.read_text())
    assert isinstance(doc, dict), "the workflow is not a YAML mapping"
    return doc


def _steps(doc: dict) -> list[dict]:
    return [s for job in doc["jobs"].values() for s in job["steps"]]


def _command(doc: dict, program: str) -> list[str]:
    """The argv of the one `run:` line starting with `program`, with the workflow's env variables expanded."""
    env = {**doc.get("env", {}), **{k: v for job in doc["jobs"].values() for k, v in job.get("env", {}).items()}}
    lines = [s["run"] for s in _steps(doc) if program in s.get("run", "")]
    assert len(lines) == 1, f"expected one step running {program!r}, found {len(lines)}"
    text = re.sub(r"\$\{?(\w+)\}?", lambda m: str(env[m.group(1)]), lines[0])
    argv = shlex.split(text)
    assert argv[:2] == program.split()
    return argv[2:]


def test_workflow_is_valid_yaml_with_the_expected_shape():
    doc = _workflow()
    assert doc["name"] == "transfer-gate"
    on = doc.get("on", doc.get(True))  # YAML 1.1 reads the bare key `on` as True
    assert any("checkpoints/" in p for p in on["pull_request"]["paths"])  # runs when a checkpoint changes
    uses = [s.get("uses", "") for s in _steps(doc)]
    assert any(u.startswith("actions/cache@") for u in uses)  # the baseline run is cached
    assert any(u.startswith("actions/upload-artifact@") for u in uses)  # the HTML report is uploaded
    assert any("bench report" in s.get("run", "") for s in _steps(doc))
    assert any("GITHUB_STEP_SUMMARY" in s.get("run", "") and "verdict.md" in s.get("run", "") for s in _steps(doc))


def test_workflow_gate_command_line_is_accepted_by_bench_regress():
    argv = _command(_workflow(), "bench regress")
    cfg, forwarded, _ = regress_args.parse_args(argv)  # the real argument handling; nothing is run
    assert cfg.candidate == "checkpoints/policy.safetensors" and cfg.baseline == "baseline-run/baseline"
    assert cfg.out == "gate/verdict.json" and not cfg.plan
    # the check bites: one misspelt key and the same line is refused
    with pytest.raises(ConfigError, match="unknown key 'margn'"):
        regress_args.parse_args([*argv, "margn=0.1"])


def test_workflow_baseline_run_is_where_the_gate_reads_it():
    doc = _workflow()
    run_cfg = api.config_from_argv(_command(doc, "bench run"))  # typed by the runner, suite and policy
    gate_cfg, _, _ = regress_args.parse_args(_command(doc, "bench regress"))
    assert str(Path(run_cfg.out) / str(run_cfg.run_id)) == gate_cfg.baseline
    assert run_cfg.policy_options["checkpoint"] == "baseline/policy.safetensors"
