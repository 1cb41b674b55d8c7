"""The regression gate end to end: pairing records, the CLI, its outputs and its refusals (statistics: test_gate.py)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from bench.board.gate.pairs import cell_counts, pair_records
from bench.core.errors import DataError
from bench.protocols.suite import episode_seed
from bench.records import EpisodeRecord
from tests.fixtures import record

REPO = Path(__file__).resolve().parents[1]


def rec(
    robot: str,
    episode: int,
    success: bool,
    *,
    seed: int | None = None,
    error: str | None = None,
    init: str | None = "h",
    policy: str = "p",
    split: str = "seen",
) -> EpisodeRecord:
    return record(
        success,
        robot=robot,
        episode=episode,
        split=split,
        seed=episode_seed(0, episode) if seed is None else seed,
        init_state_hash=f"{init}{robot}{episode}" if init else None,
        error=error,
        policy=policy,
    )


def test_pairing_by_cell_and_episode_counts_errors_as_failures():
    cand = [
        rec("A", 0, True),
        rec("A", 1, False, error="boom"),
        rec("A", 2, True),
        rec("B", 0, False),
        rec("B", 1, False, error="timeout"),
    ]
    base = [rec("A", 0, True), rec("A", 1, True), rec("B", 0, True), rec("B", 1, False, error="timeout")]
    out = pair_records(cand, base)  # A/2 has no twin; B/1 errored on both sides
    assert out["errors"] == {"candidate": 1, "baseline": 0, "both": 1} and out["unpaired"] == 1
    pairs = {k[1]: [(b.success_once, c.success_once) for b, c in v] for k, v in out["cells"].items()}
    assert pairs == {"A": [(True, True), (True, False)], "B": [(True, False)]}
    counts = {k[1]: v for k, v in cell_counts(out["cells"], "success_once").items()}
    assert counts["A"].as_row() == [1, 1, 0, 0] and counts["B"].as_row() == [0, 1, 0, 0]  # errored = failed


def test_pairing_refuses_different_seeds_or_initial_states():
    with pytest.raises(DataError, match="seeds differ"):
        pair_records([rec("A", 0, True, seed=1)], [rec("A", 0, True, seed=2)])
    with pytest.raises(DataError, match="initial states differ"):
        pair_records([rec("A", 0, True, init="x")], [rec("A", 0, True, init="y")])


# -- CLI ----------------------------------------------------------------------------------------
def _bench(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bench", *args], capture_output=True, text=True, cwd=cwd, timeout=600)


def _regress_against_base(tmp_path: Path, *args: str, cwd: Path) -> subprocess.CompletedProcess:
    """`bench regress` of the scripted candidate against the recorded run tmp_path/base: gate run g, verdict v.json."""
    baseline, verdict = f"baseline={tmp_path / 'base'}", f"out={tmp_path / 'v.json'}"
    return _bench(
        "regress", "candidate=scripted", baseline, "workers=1", f"runs={tmp_path}", "run_id=g", verdict, *args, cwd=cwd
    )


def _one_line_error(res: subprocess.CompletedProcess, match: str) -> None:
    assert res.returncode == 2, res.stderr[-1500:]
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error:") and match in lines[0], res.stderr


@pytest.mark.parametrize(
    "args, match",
    [
        (["candidate=random"], "baseline= is required"),
        (["candidate=random", "baseline=scripted", "policy=x"], "key 'policy' is not valid for bench regress"),
        (["candidate=random", "baseline=scripted", "margn=0.1"], "unknown key 'margn'"),
        (["candidate=randm", "baseline=scripted"], "Did you mean 'random'"),
        (["candidate=random", "baseline=scripted", "margin=1.5"], "margin=1.5"),
        (["candidate=random", "baseline=nope/run"], "no such file or directory"),
    ],
    ids=["no-baseline", "policy-key", "typo-key", "typo-policy", "bad-margin", "missing-dir"],
)
def test_bad_arguments_exit_2(tmp_path: Path, args, match):
    _one_line_error(_bench("regress", *args, f"runs={tmp_path / 'runs'}", cwd=tmp_path), match)
    assert not (tmp_path / "runs").exists()


def test_foreign_or_corrupt_json_baseline_exits_2(tmp_path: Path):
    foreign = tmp_path / "foreign.json"
    foreign.write_text(json.dumps({"hello": "world"}))
    _one_line_error(_bench("regress", "candidate=random", f"baseline={foreign}", cwd=tmp_path), "not a checkpoint")
    run = tmp_path / "brokenrun"
    run.mkdir()
    (run / "run.json").write_text("{not json")
    _one_line_error(_bench("regress", "candidate=random", f"baseline={run}", cwd=tmp_path), "not valid JSON")
    (run / "run.json").write_text(json.dumps({"schema": "something/else"}))
    _one_line_error(_bench("regress", "candidate=random", f"baseline={run}", cwd=tmp_path), "not a bench run.json")


def test_gate_detects_random_policy_against_expert(tmp_path: Path):
    """1 robot x 6 paired episodes: the expert succeeds, random never does -> regression, exit 1, CI outputs beside."""
    res = _bench(
        "regress",
        "candidate=random",
        "baseline=scripted",
        "robots=[Panda]",
        "episodes=6",
        "batch=0",
        "horizon=70",
        "workers=1",
        f"runs={tmp_path}",
        "run_id=g",
        cwd=tmp_path,
    )
    assert res.returncode == 1, res.stderr[-2000:]
    v = json.loads((tmp_path / "g" / "verdict.json").read_text())
    assert v["schema"] == "bench.regress/2" and v["verdict"] == "regression" and v["looks"][-1]["baseline_only"] == 6
    assert v["cells"][0]["baseline"] == 1.0 and v["cells"][0]["candidate"] == 0.0 and v["cells"][0]["regressed"]
    assert [r["id"] for r in v["regressed"]] == ["pooled"]  # one cell: its test is the pooled one
    assert v["regressed"][0]["lcb"] > v["margin"] and v["candidate"]["provenance"] is None  # no checkpoint
    # both sides are ordinary runs with the same episode seeds
    seeds = [
        sorted(json.loads(line)["seed"] for line in (tmp_path / "g" / f"g-{s}" / "episodes.jsonl").open())
        for s in ("candidate", "baseline")
    ]
    assert seeds[0] == seeds[1] == sorted(episode_seed(0, e) for e in range(6))
    # JUnit: one case per cell (failed), the aggregate tests, the verdict (failed: exit 1)
    root = ET.parse(tmp_path / "g" / "verdict.junit.xml").getroot()
    cases = {(c.get("classname"), c.get("name")): c for c in root.iter("testcase")}
    assert cases[("bench-regress.cells", "Lift/Panda/default (seen)")].find("failure") is not None
    assert cases[("bench-regress.verdict", "verdict")].find("failure") is not None
    assert root.get("failures") == str(sum(1 for c in cases.values() if c.find("failure") is not None))
    md = (tmp_path / "g" / "verdict.md").read_text()
    assert "regression (exit 1)" in md and "| Lift/Panda/default | seen | 6 | 100% | 0% | +1.00 |" in md
    # the HTML report takes the new verdict
    rep = _bench(
        "report",
        str(tmp_path / "g" / "g-candidate"),
        f"out={tmp_path / 'rep'}",
        f"verdict={tmp_path / 'g' / 'verdict.json'}",
        cwd=tmp_path,
    )
    assert rep.returncode == 0, rep.stderr[-1500:]
    assert "Regressed" in (tmp_path / "rep" / "index.html").read_text()


def _run(tmp_path: Path, run_id: str, *args: str) -> Path:
    res = _bench("run", *args, "horizon=70", "workers=1", f"run_id={run_id}", f"out={tmp_path}", cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-2000:]
    return tmp_path / run_id


def _mixed_run(tmp_path: Path, name: str, base: Path, replace: Path, robot: str) -> Path:
    """`base` with `robot`'s episodes taken from the run `replace` (real rollouts of another policy)."""
    out = tmp_path / name
    out.mkdir()
    lines = [ln for ln in (base / "episodes.jsonl").read_text().splitlines() if json.loads(ln)["robot"] != robot]
    lines += [ln for ln in (replace / "episodes.jsonl").read_text().splitlines() if json.loads(ln)["robot"] == robot]
    (out / "episodes.jsonl").write_text("\n".join(lines) + "\n")
    meta = json.loads((base / "run.json").read_text())
    meta.update(run_id=name, policy={"name": f"mixed ({robot}: other)", "checkpoint": None, "checkpoint_sha256": None})
    (out / "run.json").write_text(json.dumps(meta))
    return out


def test_gate_names_the_one_robot_that_collapsed(tmp_path: Path):
    """Real rollouts: the expert on Panda and IIWA vs the same run with Panda played by the random policy."""
    base = _run(tmp_path, "base", "policy=scripted", "robots=[Panda,IIWA]", "episodes=8")
    bad = _run(tmp_path, "bad", "policy=random", "robots=[Panda]", "episodes=8")
    cand = _mixed_run(tmp_path, "cand", base, bad, "Panda")
    res = _bench(
        "regress",
        f"candidate={cand}",
        f"baseline={base}",
        f"runs={tmp_path}",
        "run_id=g",
        f"out={tmp_path / 'v.json'}",
        cwd=tmp_path,
    )
    assert res.returncode == 1, res.stderr[-2000:]
    v = json.loads((tmp_path / "v.json").read_text())
    cells = {c["robot"]: c for c in v["cells"]}
    assert cells["Panda"]["regressed"] and cells["Panda"]["drop"] == cells["Panda"]["baseline"] > 0.5
    assert not cells["IIWA"]["regressed"] and cells["IIWA"]["drop"] == 0
    named = {r["name"] for r in v["regressed"] if r["kind"] == "cell"}
    assert named == {"Lift/Panda/default"} and v["regressed"][0]["kind"] == "cell"
    assert "cell **Lift/Panda/default**" in (tmp_path / "v.md").read_text()


def test_gate_reuses_a_recorded_baseline_run(tmp_path: Path):
    base = _bench(
        "run",
        "policy=scripted",
        "robots=[Panda]",
        "episodes=2",
        "horizon=70",
        "workers=1",
        "seed=3",
        "run_id=base",
        f"out={tmp_path}",
        cwd=tmp_path,
    )
    assert base.returncode == 0, base.stderr[-2000:]
    before = (tmp_path / "base" / "episodes.jsonl").read_bytes()
    res = _regress_against_base(tmp_path, cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-2000:]  # 2 identical pairs: inconclusive, passes (not strict)
    v = json.loads((tmp_path / "v.json").read_text())
    assert v["baseline"]["reused"] is True and v["seed"] == 3 and v["verdict"] == "inconclusive"
    assert v["looks"][-1]["baseline_only"] == v["looks"][-1]["candidate_only"] == 0
    assert not (tmp_path / "g" / "g-baseline").exists()
    assert (tmp_path / "base" / "episodes.jsonl").read_bytes() == before
    # a different seed than the recorded baseline's is refused (the episodes would not pair)
    _one_line_error(
        _bench(
            "regress", "candidate=scripted", f"baseline={tmp_path / 'base'}", "seed=4", f"runs={tmp_path}", cwd=tmp_path
        ),
        "seed=4 differs from the baseline run",
    )
    # a different horizon or other robots (other suite cells) are refused too, naming the key; nothing is written
    for key, match in (
        ("horizon=80", "horizon=80 differs from the baseline run"),
        ("robots=[IIWA]", "robots=['IIWA'] differs from the baseline run"),
    ):
        _one_line_error(
            _bench(
                "regress",
                "candidate=scripted",
                f"baseline={tmp_path / 'base'}",
                key,
                f"runs={tmp_path / 'refused'}",
                cwd=tmp_path,
            ),
            match,
        )
    assert not (tmp_path / "refused").exists()


def _doctored(tmp_path: Path, base: Path, name: str, edit) -> Path:
    out = tmp_path / name
    shutil.copytree(base, out)
    recs = [edit(json.loads(line)) for line in (base / "episodes.jsonl").read_text().splitlines()]
    (out / "episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in recs if r is not None))
    return out


def test_baseline_run_with_other_cells_or_seeds_is_refused_before_any_episode(tmp_path: Path, capsys):
    """Runs whose records do not match the candidate's plan (another bench's seeding, a cell missing) -> exit 2."""
    from bench import cli

    base = _run(tmp_path, "base", "policy=scripted", "robots=[Panda,IIWA]", "episodes=2")
    reseeded = _doctored(tmp_path, base, "reseeded", lambda r: {**r, "seed": r["seed"] + 1})
    partial = _doctored(tmp_path, base, "partial", lambda r: r if r["robot"] == "Panda" else None)
    for baseline, match in (
        (reseeded, "was made with other episode seeds: Lift/"),
        (partial, "was made with other suite cells: it lacks cell Lift/IIWA/default/nominal"),
    ):
        runs = tmp_path / f"runs-{baseline.name}"
        assert cli.main(["regress", "candidate=random", f"baseline={baseline}", f"runs={runs}"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and match in err[0], err
        assert not runs.exists()  # no candidate episode was run
    # outputs may not land inside an input; metric=return is not a success rate
    for args, match in (
        ([f"baseline={base}", f"out={base / 'verdict.json'}"], "would be written inside the baseline run directory"),
        (["baseline=scripted", "metric=return"], "metric='return': the gate compares success"),
    ):
        assert cli.main(["regress", "candidate=random", f"runs={tmp_path / 'r'}", *args]) == 2
        assert match in capsys.readouterr().err
    assert not (base / "verdict.json").exists() and not (tmp_path / "r").exists()


def test_identical_checkpoints_run_nothing_and_say_so(tmp_path: Path):
    """Same sha256 (a copy of the committed BC checkpoint vs the committed run recorded with it): no episode."""
    ckpt = REPO / "baselines" / "checkpoints" / "bc_lift_seen40.safetensors"
    copy = tmp_path / "new.safetensors"
    shutil.copy(ckpt, copy)
    shutil.copy(ckpt.with_suffix(".json"), copy.with_suffix(".json"))
    for baseline in (ckpt, REPO / "results" / "runs" / "held_out_robots-bc-s0"):
        out = tmp_path / f"v-{baseline.stem}.json"
        res = _bench(
            "regress",
            f"candidate={copy}",
            f"baseline={baseline}",
            f"runs={tmp_path / 'runs'}",
            f"out={out}",
            "strict=true",
            cwd=tmp_path,
        )
        assert res.returncode == 0, res.stderr[-2000:]
        v = json.loads(out.read_text())
        assert v["identical"] and v["verdict"] == "no_regression" and v["looks"] == [] and "no episode" in v["note"]
        prov = v["candidate"]["provenance"]
        assert prov["sha256"] == v["baseline"]["checkpoint_sha256"] and prov["size_bytes"] == ckpt.stat().st_size
        assert prov["training"]["algorithm"] == "bc" and prov["architecture"] == "mlp"
        assert len(v["planned_cells"]) == 7
        skipped = ET.parse(out.with_suffix(".junit.xml")).getroot().findall(".//skipped")
        assert len(skipped) == 7 and "same checkpoint" in out.with_suffix(".md").read_text()
    assert not (tmp_path / "runs").exists()  # no run directory: nothing was simulated


def test_plan_prints_the_budget_for_a_stated_power(tmp_path: Path):
    res = _bench("regress", "plan=true", "power=0.8", "drop=0.6", "rate=0.9", cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-1500:]
    assert "7 cells (seen: 3, unseen: 4) (suite held_out_robots: 7 cells x 1 condition(s))" in res.stdout
    row = next(line for line in res.stdout.splitlines() if "one cell 0.90 -> 0.30" in line).split()
    need, power = int(row[-4]), float(row[-2])
    assert need % 5 == 0 and power >= 0.8
    res = _bench("regress", "plan=true", "cells=3", "robots=[Panda]", "batch=0", "drop=0.5", "rate=0.5", cwd=tmp_path)
    assert res.returncode == 0 and "budget plan: 3 cells;" in res.stdout and "one look at the end" in res.stdout
    _one_line_error(_bench("regress", "plan=true", "drop=0.04", cwd=tmp_path), "drop=0.04: must exceed margin=0.05")
    _one_line_error(_bench("regress", "plan=true", "power=1.5", cwd=tmp_path), "power=1.5: must be in (0, 1)")
    assert list(tmp_path.iterdir()) == []  # plan writes nothing


def test_a_side_that_measured_nothing_fails_the_gate_with_exit_3(tmp_path: Path):
    """A baseline whose robot-c episodes all errored passes no candidate: the gate exits 3, not 0."""
    base = _bench(
        "run",
        "suite=tests.toy_suite:ToySuite",
        "fault=raise",
        "episodes=4",
        "workers=1",
        "n_boot=200",
        "run_id=base",
        f"out={tmp_path}",
        cwd=REPO,
    )
    assert base.returncode == 3, base.stderr[-2000:]  # the baseline run itself says so
    assert "nothing measured: run base" in base.stderr and "1 of 3 cells completed no episode (reach/c/line)" in (
        base.stderr
    )
    # the baseline's suite faulted on purpose (fault=raise); the candidate's does not
    res = _regress_against_base(tmp_path, "allow_spec_change=true", cwd=REPO)
    assert res.returncode == 3, res.stderr[-2000:]
    last = res.stderr.strip().splitlines()[-1]
    assert last.startswith("nothing measured: regress g: the baseline completed no episode in 1 of 3 cells")
    assert "RuntimeError: toy env exploded" in last
    v = json.loads((tmp_path / "v.json").read_text())
    assert v["verdict"] == "nothing_measured" and v["exit_code"] == 3 and v["note"].startswith("nothing measured:")
    failures = ET.parse(tmp_path / "v.junit.xml").getroot().findall(".//testcase[@name='verdict']/failure")
    assert failures and failures[0].get("message") == "NOTHING MEASURED (exit 3)"
