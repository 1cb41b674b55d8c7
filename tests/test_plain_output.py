"""What a pipe, a file or a CI log gets from the printed tables (stdout not a terminal; pytest captures it): full
names, intervals on one line, and a gap of zero said in words (bench.core.console, bench.scoring.summary)."""

from __future__ import annotations

import json
from pathlib import Path

from bench.cli import main
from bench.scoring.summary import fmt_estimate, gap_sentence, render

RESULTS = Path(__file__).resolve().parents[1] / "results"


def _gap_summary(value: float) -> dict:
    return {
        "metric": "success_once",
        "confidence": 0.95,
        "suite": {"manifest": {"robots": {"seen": ["Panda"], "unseen": ["UR5e"]}}},
        "gaps": [{"metric": "success_once", "kind": "seen-unseen", "value": value, "ci": [-0.1, 0.09]}],
    }


def test_a_zero_gap_is_said_to_be_no_difference():
    """`+0.000` was read out as "0 points higher"; under half a point it was "0 points" too."""
    committed = json.loads((RESULTS / "runs" / "held_out_robots-scripted-s0" / "summary.json").read_text())
    for summary in (committed, _gap_summary(0.0)):
        sentence = gap_sentence(summary)
        assert sentence is not None and "0 points" not in sentence, sentence
        assert "the policy's success rate is the same as on the seen ones (gap +0.000 [" in sentence, sentence
    assert "success rate is less than 1 point lower than on the seen ones" in str(gap_sentence(_gap_summary(0.004)))
    assert "success rate is 12 points higher than on the seen ones" in str(gap_sentence(_gap_summary(-0.12)))


def test_leaderboard_show_in_a_pipe_keeps_names_and_intervals_whole(capsys):
    assert main(["leaderboard", "show", str(RESULTS / "leaderboard.json")]) == 0
    out = capsys.readouterr().out
    assert "…" not in out
    lines = out.splitlines()
    board = json.loads((RESULTS / "leaderboard.json").read_text())
    for e in board["entries"]:
        row = next((ln for ln in lines if f" {e['run_id']} " in ln), None)  # the run id whole, on its row
        assert row is not None, e["run_id"]
        score = fmt_estimate(e["score"], pct=e["metric"] != "return", signed=False)
        assert f"{e['score']['split'] or ''} {score}" in row, (score, row)


def test_a_run_summary_in_a_pipe_prints_full_condition_names(capsys):
    """A sensitivity table's conditions (`damping~from(calibration@...)`) were cut at 120 columns."""
    sweep = json.loads((RESULTS / "real_panda" / "sweep.json").read_text())
    summary = json.loads((RESULTS / "runs" / "held_out_robots-bc-s0" / "summary.json").read_text())
    render({**summary, "sensitivity": sweep["sensitivity"]})
    out = capsys.readouterr().out
    assert "…" not in out
    for entry in sweep["sensitivity"]:
        assert f"│ {entry['condition']} " in out, entry["condition"]
    assert any(ln.startswith("How to read this: ") and ln.endswith("unseen robots.") for ln in out.splitlines())
