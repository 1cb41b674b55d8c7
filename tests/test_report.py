"""`bench report`: HTML + PNG figures for runs (with sensitivity), leaderboards, calibration and verdicts."""

from __future__ import annotations

import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from test_leaderboard import ALL, summary  # shared synthetic summaries (tests/ is on sys.path)

from bench import cli
from bench.board.leaderboard import merge
from bench.scoring.summary import build
from tests.fixtures import record


def _perturbed_summary() -> dict:
    recs = []
    for robot, split in (("A", "seen"), ("C", "unseen")):
        for cond, axis, level, p in (
            ("nominal", None, None, 0.9),
            ("friction=0.5", "friction", 0.5, 0.6),
            ("friction=2", "friction", 2.0, 0.8),
            ("mass=[1,3]", "mass", [1.0, 3.0], 0.3),
        ):
            for e in range(10):
                ok = e < round(p * 10)
                recs.append(
                    record(
                        ok,
                        run_id="pert",
                        suite="toy",
                        robot=robot,
                        split=split,
                        condition=cond,
                        axis=axis,
                        level=level,
                        params={axis: 1.0} if axis else {},
                        episode=e,
                        seed=e,
                        return_=float(ok),
                        length=5,
                    )
                )
    base = summary("tmp", "p", ALL)
    meta = {k: base[k] for k in ("suite", "policy", "config", "provenance")}
    meta["run_id"], meta["expected_episodes"] = "pert", len(recs)
    return build(recs, run_meta=meta).to_json()


def _pngs_ok(out: Path, names: set[str]) -> None:
    assert {p.name for p in out.glob("*.png")} == names
    for p in out.glob("*.png"):
        with Image.open(p) as im:
            assert im.size[0] > 300 and im.size[1] > 150
            assert len(im.convert("L").getcolors(maxcolors=1 << 16) or []) > 5  # something is drawn
    page = (out / "index.html").read_text()
    for n in names:
        assert f"src='{n}'" in page


def test_run_report_with_sensitivity(tmp_path: Path, capsys):
    s = _perturbed_summary()
    assert s.get("sensitivity")
    run = tmp_path / "run"
    run.mkdir()
    (run / "summary.json").write_text(json.dumps(s))
    out = tmp_path / "report"
    assert cli.main(["report", str(run), f"out={out}"]) == 0
    _pngs_ok(out, {"cells.png", "gaps.png", "sensitivity.png"})
    page = (out / "index.html").read_text()
    assert "Sensitivity per perturbation axis" in page and "friction" in page and "mass" in page
    assert "seen" in page and "unseen" in page


def test_run_report_reads_the_gap_and_aggregates_as_the_console_does(tmp_path: Path):
    """The page holds what `bench run` ends with: the aggregates table and the sentence on how to read the gap,
    from their owner in bench.scoring.summary (the same text, HTML-escaped)."""
    import html

    from bench.scoring.summary import aggregates, gap_sentence

    run = Path(__file__).resolve().parents[1] / "results" / "runs" / "held_out_robots-bc-s0"
    doc = json.loads((run / "summary.json").read_text())
    out = tmp_path / "report"
    assert cli.main(["report", str(run / "summary.json"), f"out={out}"]) == 0
    page = html.unescape((out / "index.html").read_text())
    sentence = gap_sentence(doc)
    assert sentence and sentence.startswith("How to read this: ") and f"<p><b>{sentence}</b></p>" in page
    assert page.index(sentence) < page.index("<h2>")  # the page's first word on the run
    title, header, rows = aggregates(doc)
    assert title.capitalize() in page
    assert "<tr>" + "".join(f"<th>{h}</th>" for h in header) + "</tr>" in page
    for row in rows:
        assert "<tr>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>" in page, row


def test_leaderboard_report_with_calibration_and_verdict(tmp_path: Path):
    board = merge([("a", summary("a", "expert", ALL)), ("b", summary("b", "random", {k: 0.1 for k in ALL}))])
    (tmp_path / "lb.json").write_text(json.dumps(board))
    cal = {
        "schema": "bench.calibration/1",
        "errors": {
            stage: {
                "one_step_nrmse": v,
                "k_step_nrmse": 2 * v,
                "free_run_nrmse": 3 * v,
                "free_run_rmse": v,
                "r2": 1 - v,
            }
            for stage, v in (("nominal", 0.3), ("declared", 0.1), ("final", 0.05))
        },
        "added": [{"name": "coulomb"}],
    }
    (tmp_path / "cal").mkdir()
    (tmp_path / "cal" / "calibration.json").write_text(json.dumps(cal))
    out = tmp_path / "rep"
    assert cli.main(["report", str(tmp_path / "lb.json"), f"out={out}", f"calibration={tmp_path / 'cal'}"]) == 0
    _pngs_ok(out, {"leaderboard.png", "calibration.png"})
    page = (out / "index.html").read_text()
    assert "coulomb" in page and "expert" in page and "declared" in page
    # replacing an existing report leaves no stale figure behind
    assert cli.main(["report", str(tmp_path / "lb.json"), f"out={out}"]) == 2  # exists: needs overwrite=true
    assert cli.main(["report", str(tmp_path / "lb.json"), f"out={out}", "overwrite=true"]) == 0
    _pngs_ok(out, {"leaderboard.png"})


@pytest.mark.parametrize(
    "make_input, match",
    [
        (lambda d: d / "missing", "no such file"),
        (lambda d: (d / "x.json").write_text("{oops") and d / "x.json", "not valid JSON"),
        (lambda d: (d / "y.json").write_text('{"a": 1}') and d / "y.json", "not a bench result"),
    ],
    ids=["missing", "corrupt", "foreign"],
)
def test_bad_input_exits_2_and_writes_nothing(tmp_path: Path, capsys, make_input, match):
    src = make_input(tmp_path)
    out = tmp_path / "rep"
    assert cli.main(["report", str(src), f"out={out}"]) == 2
    err = capsys.readouterr().err
    assert match in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_bad_calibration_exits_2(tmp_path: Path, capsys):
    (tmp_path / "s.json").write_text(json.dumps(summary("s", "p", ALL)))
    (tmp_path / "c.json").write_text(json.dumps({"schema": "bench.calibration/1", "errors": []}))
    assert (
        cli.main(["report", str(tmp_path / "s.json"), f"out={tmp_path / 'r'}", f"calibration={tmp_path / 'c.json'}"])
        == 2
    )
    assert "errors must hold" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


def test_returns_are_shown_as_returns_and_stderr_stays_clean(tmp_path: Path, capsys):
    """The committed leaderboard holds HalfCheetah scored by return (-274.6): never a percentage; no warning."""
    repo = Path(__file__).resolve().parents[1]
    out = tmp_path / "lb"
    assert cli.main(["report", str(repo / "results" / "leaderboard.json"), f"out={out}"]) == 0
    assert capsys.readouterr().err == ""  # no library warning (matplotlib layout) reaches stderr
    page = (out / "index.html").read_text()
    gym = page[page.index("<h2>gym v1") :].split("</table>")[0]
    assert "seen -274.6 [-364.1, -229.4" in gym and "%" not in gym.split("<table>")[1]
    assert "-27460%" not in page
    assert Image.open(out / "leaderboard.png").size[0] > 1000
    run = tmp_path / "run"
    assert cli.main(["report", str(repo / "results" / "runs" / "gym-HalfCheetah-random-s0"), f"out={run}"]) == 0
    assert capsys.readouterr().err == ""
    cells = (run / "index.html").read_text()
    assert "<h2>Return per cell</h2>" in cells and "<th>mean return</th>" in cells and "-274.6 [" in cells


# -- a checkpoint sweep (bench sweep's folder) ------------------------------------------------------
def _sweep_folder(tmp_path: Path) -> Path:
    """A sweep folder as `bench sweep` leaves it: sweep.json from the real selection (`bench.scoring.sweep.select`)
    over three checkpoints on common seeds, and a leaderboard.json beside it (the committed one)."""
    from bench.scoring.sweep import Point, select

    rng = np.random.default_rng(0)
    u = rng.random(40)
    points = [Point(f"step{s}", float(s), {("c", "n", e): float(u[e] < r) for e in range(40)}) for s, r in
              ((1000, 0.2), (2000, 0.7), (3000, 0.75))]  # fmt: skip
    doc = {"schema": "bench.sweep/1", "metric": "success_once", "step_source": "file name", "min_success": None}
    doc.update(select(points, 0.05), exit_code=0)
    folder = tmp_path / "sw"
    folder.mkdir()
    (folder / "sweep.json").write_text(json.dumps(doc))
    shutil.copy(Path(__file__).resolve().parents[1] / "results" / "leaderboard.json", folder / "leaderboard.json")
    return folder


def test_a_sweep_folder_is_reported_with_its_curve_table_and_leaderboard(tmp_path: Path, capsys):
    folder = _sweep_folder(tmp_path)
    doc = json.loads((folder / "sweep.json").read_text())
    out = tmp_path / "rep"
    assert cli.main(["report", str(folder), f"out={out}"]) == 0
    page = (out / "index.html").read_text()
    assert "<h2>Checkpoint sweep</h2>" in page and "sweep.png" in page and (out / "sweep.png").stat().st_size > 0
    assert f"Selected: <b>{doc['selected']}</b>" in page and "beaten by" in page and "step1000" in page
    assert "leaderboard.png" in page  # the per-checkpoint entries beside the sweep
    # sweep.json itself, without a leaderboard beside it: the sweep sections only
    alone = tmp_path / "alone"
    alone.mkdir()
    shutil.copy(folder / "sweep.json", alone / "sweep.json")
    assert cli.main(["report", str(alone / "sweep.json"), f"out={tmp_path / 'rep2'}"]) == 0
    assert "leaderboard.png" not in (tmp_path / "rep2" / "index.html").read_text()
    capsys.readouterr()


@pytest.mark.parametrize(
    "change,match",
    [
        (lambda d: d.update(selected="step9"), "field selected names 'step9', not one of the sweep's checkpoints"),
        (lambda d: d["checkpoints"][0]["success"].update(ci=[0.1, 1.4]), "a success rate's interval lies in"),
        (lambda d: d.pop("best_set"), "'best_set' is a required property"),
        (lambda d: d.update(metric="return"), "field \\$.metric"),
    ],
)
def test_a_bad_sweep_is_one_line_exit_2_nothing_written(tmp_path: Path, capsys, change, match):
    folder = _sweep_folder(tmp_path)
    doc = json.loads((folder / "sweep.json").read_text())
    change(doc)
    (folder / "sweep.json").write_text(json.dumps(doc))
    out = tmp_path / "rep"
    assert cli.main(["report", str(folder), f"out={out}"]) == 2
    err = capsys.readouterr().err
    assert re.search(match, err) and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_a_broken_leaderboard_beside_a_sweep_is_refused(tmp_path: Path, capsys):
    folder = _sweep_folder(tmp_path)
    (folder / "leaderboard.json").write_text(json.dumps({"schema": "bench.leaderboard/1", "entries": 3}))
    assert cli.main(["report", str(folder), f"out={tmp_path / 'rep'}"]) == 2
    assert "leaderboard.json" in capsys.readouterr().err and not (tmp_path / "rep").exists()
