"""Per-axis sensitivity: pairing by seed, McNemar, intervals, schema, table."""

import json

import numpy as np
import pytest
from scipy.stats import binomtest

from bench.scoring import sensitivity as sens
from bench.scoring import stats as sc
from tests.fixtures import provenance, record


def rec(
    condition, episode, success, robot="Panda", axis=None, level=None, params=None, error=None, at_end=None, ret=0.0
):
    return record(
        condition=condition,
        episode=episode,
        robot=robot,
        axis=axis,
        level=level,
        params=params or {},
        seed=1000 + episode,
        success_once=bool(success),
        success_at_end=bool(success if at_end is None else at_end),
        return_=float(ret),
        error=error,
        wall_s=0.1,
        worker_pid=1,
    )


def run_records(nominal, perturbed, axis="friction", level=0.1, robot="Panda"):
    name = f"{axis}={level:g}"
    return [rec("nominal", i, s, robot) for i, s in enumerate(nominal)] + [
        rec(name, i, s, robot, axis, level, {axis: level}) for i, s in enumerate(perturbed)
    ]


def entries_for(records, **kw):
    return sens.sensitivity(
        records, np.random.default_rng(0), n_boot=kw.get("n_boot", 1000), confidence=kw.get("confidence", 0.95)
    )


def test_drop_is_paired_by_episode_and_tested_with_mcnemar():
    nominal = [1] * 10
    perturbed = [1, 0, 1, 0, 1, 0, 1, 0, 0, 0]
    out = entries_for(run_records(nominal, perturbed))
    assert [e["condition"] for e in out] == ["nominal", "friction=0.1"]
    e = out[1]
    assert e["axis"] == "friction" and e["level"] == 0.1 and e["kind"] == "grid" and e["scope"] == "all"
    assert e["success_once"]["successes"] == 4 and e["success_once"]["value"] == pytest.approx(0.4)
    lo, hi = e["success_once"]["ci"]
    ci = binomtest(4, 10).proportion_ci(0.95, method="wilson")
    assert (lo, hi) == (pytest.approx(ci.low, abs=1e-6), pytest.approx(ci.high, abs=1e-6))
    d = e["drop_vs_nominal"]["success_once"]
    assert d["value"] == pytest.approx(0.6) and d["n_pairs"] == 10
    assert d["lost"] == 6 and d["gained"] == 0
    assert d["p_value"] == pytest.approx(binomtest(6, 6, 0.5).pvalue, abs=1e-6)
    assert 0 < d["ci"][0] <= 0.6 <= d["ci"][1] <= 1
    assert out[0]["drop_vs_nominal"]["success_once"]["value"] is None  # nominal is the reference


def test_pairing_uses_the_same_episode_not_the_order_of_records():
    # nominal succeeds exactly on even episodes, the perturbation flips nothing: a paired drop of 0
    recs = run_records([1, 0] * 5, [1, 0] * 5)
    recs = list(reversed(recs))
    d = entries_for(recs)[1]["drop_vs_nominal"]["success_once"]
    assert d["value"] == 0 and d["lost"] == d["gained"] == 0 and d["p_value"] == 1.0
    # no discordant pair of 10 is not proof of no effect: Tango's interval is symmetric about 0, not [0, 0]
    assert d["ci"][0] == -d["ci"][1] and 0.2 < d["ci"][1] < 0.35


def test_paired_interval_is_tighter_than_unpaired_when_outcomes_share_the_initial_state():
    rng = np.random.default_rng(3)
    hard = rng.random(40) < 0.5  # episodes whose initial state is hard fail under both conditions
    nominal = (~hard).astype(int)
    perturbed = nominal.copy()
    perturbed[np.flatnonzero(nominal)[:4]] = 0  # the perturbation breaks 4 of the easy ones
    d = entries_for(run_records(nominal, perturbed))[1]["drop_vs_nominal"]["success_once"]
    paired_width = d["ci"][1] - d["ci"][0]
    from bench.scoring.stats import Boot, gap

    unpaired = gap([nominal.astype(float)], [perturbed.astype(float)], np.random.default_rng(0), Boot(n_boot=1000))
    assert paired_width < 0.6 * (unpaired.hi - unpaired.lo)
    assert d["value"] == pytest.approx(0.1)


def test_errors_are_left_out_of_pairs_and_rates():
    recs = run_records([1, 1, 1, 1], [0, 0, 1, 1])
    recs[5] = rec("friction=0.1", 1, False, axis="friction", level=0.1, error="timeout after 1 s at step 3")
    e = entries_for(recs)[1]
    assert e["n"] == 3 and e["errors"] == 1
    assert e["drop_vs_nominal"]["success_once"]["n_pairs"] == 3
    assert e["drop_vs_nominal"]["success_once"]["value"] == pytest.approx(1 / 3)


def test_no_pairs_is_null_with_reason_and_json_has_no_nan():
    recs = [rec("friction=0.1", i, 1, axis="friction", level=0.1) for i in range(3)]
    out = entries_for(recs)
    d = out[0]["drop_vs_nominal"]["success_once"]
    assert d["value"] is None and "no episode completed under both" in d["reason"]
    json.dumps(out, allow_nan=False)


def test_ranges_summarise_the_sampled_values_and_sort_after_grids():
    recs = [rec("nominal", i, 1) for i in range(3)]
    recs += [
        rec("mass~U(0.5,2)", i, 1, axis="mass", level=[0.5, 2.0], params={"mass": v})
        for i, v in enumerate([0.6, 1.5, 1.9])
    ]
    recs += [rec("mass=2", i, 0, axis="mass", level=2.0, params={"mass": 2.0}) for i in range(3)]
    recs += [rec("friction=0.5", i, 1, axis="friction", level=0.5, params={"friction": 0.5}) for i in range(3)]
    out = entries_for(recs)
    assert [e["condition"] for e in out] == ["nominal", "friction=0.5", "mass=2", "mass~U(0.5,2)"]
    rng_entry = out[3]
    assert rng_entry["kind"] == "range" and rng_entry["level"] == [0.5, 2.0]
    assert rng_entry["params"] == {"mass": {"min": 0.6, "mean": pytest.approx(4.0 / 3, abs=1e-6), "max": 1.9}}


def test_per_cell_entries_and_joint_seed_resampling_with_two_cells():
    recs = run_records([1] * 6, [0] * 6, robot="Panda") + run_records([1] * 6, [1] * 6, robot="UR5e")
    out = entries_for(recs)
    pooled = [e for e in out if e["scope"] == "all" and e["axis"] == "friction"][0]
    cells = {e["robot"]: e for e in out if e["scope"] == "cell" and e["axis"] == "friction"}
    assert pooled["drop_vs_nominal"]["success_once"]["value"] == pytest.approx(0.5)
    assert pooled["drop_vs_nominal"]["success_once"]["n_pairs"] == 12
    assert cells["Panda"]["drop_vs_nominal"]["success_once"]["value"] == 1.0
    assert cells["UR5e"]["drop_vs_nominal"]["success_once"]["value"] == 0.0
    # the pooled drop's interval is Tango's over the 12 pairs of both cells (6 lost, 0 gained), not a
    # bootstrap that pins it at exactly 0.5
    lo, hi = (round(sc.paired_score_bound(6, 0, 12, 0.975, side), 6) for side in ("lower", "upper"))
    assert pooled["drop_vs_nominal"]["success_once"]["ci"] == [lo, hi] and lo < 0.5 < hi


def test_return_drop_for_tasks_without_success():
    recs = [rec("nominal", i, 0, ret=100.0 + i) for i in range(5)]
    recs += [rec("gravity=0.5", i, 0, axis="gravity", level=0.5, ret=80.0 + i) for i in range(5)]
    d = entries_for(recs)[1]["drop_vs_nominal"]["return"]
    assert d["value"] == pytest.approx(20.0) and d["ci"] == [20.0, 20.0] and d["n_pairs"] == 5


def test_summary_with_sensitivity_validates_against_the_schema():
    from bench.core.schema import validate
    from bench.scoring.summary import build

    recs = run_records([1, 1, 0, 1], [0, 1, 0, 0])
    recs += [rec("latency~U(0,4)", i, 1, axis="latency", level=[0, 4], params={"latency": i}) for i in range(4)]
    meta = {
        "run_id": "r",
        "suite": {"name": "s", "version": "1", "manifest": {}},
        "policy": {"name": "p", "checkpoint": None, "checkpoint_sha256": None},
        "config": {"seed": 0, "n_boot": 200, "confidence": 0.9},
        "expected_episodes": 12,
        "provenance": provenance(episode_seeds=[1], started_at="t"),
    }
    summary = build(recs, run_meta=meta).to_json()
    assert validate(summary) == "bench.summary/1"
    assert [e["condition"] for e in summary["sensitivity"]] == ["nominal", "friction=0.1", "latency~U(0,4)"]
    broken = json.loads(json.dumps(summary))
    broken["sensitivity"][1]["drop_vs_nominal"]["success_once"].pop("n_pairs")
    from bench.core.errors import DataError

    with pytest.raises(DataError, match=r"sensitivity\[1\]\.drop_vs_nominal\.success_once"):
        validate(broken)


def test_render_prints_conditions_intervals_and_p_values():
    from rich.console import Console

    console = Console(record=True, width=200)
    sens.render(entries_for(run_records([1] * 8, [1, 1, 0, 0, 0, 0, 0, 0])), console)
    text = console.export_text()
    assert "friction=0.1" in text and "25% [4,59]" in text and "+75 [18,93] p=0.031" in text and "p=0.031" in text
    assert "sampled" not in text  # a grid's value is its level

    recs = [rec("nominal", i, 1) for i in range(3)]
    recs += [
        rec("mass~U(0.5,2)", i, 1, axis="mass", level=[0.5, 2.0], params={"mass": v})
        for i, v in enumerate([0.6, 1.5, 1.9])
    ]
    console = Console(record=True, width=200)
    sens.render(entries_for(recs), console)
    assert "mass 0.6–1.9" in console.export_text()  # the range of values a randomised condition drew
