"""`bench predict`: prediction-powered real success (bench.scoring.predict), its coverage table at test size,
the real-table format and its bad input, and the SIMPLER tables it is demonstrated on."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from bench.api.predict import PredictConfig, predict_real
from bench.cli import main
from bench.core.errors import ConfigError, DataError
from bench.scoring.predict.ppi import Stratum, predict, trials_for_width
from bench.scoring.stats import wilson
from benchmarks.bench_predict import SIMPLER, Scenario, run, simpler_units

REPO = Path(__file__).resolve().parents[1]
REPS = 300  # Monte-Carlo s.e. of a coverage ~0.013 at 0.95
SLACK = 0.035


def _stratum(y, s=(), yu=(), sim_mean=0.5, sim_n=1000.0, key="c", weight=1.0) -> Stratum:
    return Stratum(
        key,
        weight,
        np.array(y, float),
        np.array(s, float),
        np.array(yu, float),
        sim_mean,
        sim_mean * (1 - sim_mean) / sim_n,
        sim_n,
    )


def test_no_pairs_is_exactly_wilson():
    res = predict([_stratum([], [], [1] * 7 + [0] * 3)])
    w = wilson(7, 10)
    assert res.lam == 0 and (res.lo, res.value, res.hi) == (w.lo, w.value, w.hi) == (
        res.real_lo,
        res.real_value,
        res.real_hi,
    )


def test_a_simulator_that_tracks_the_robot_narrows_the_interval():
    y = np.array([1.0] * 28 + [0.0] * 12)
    res = predict([_stratum(y, y, sim_mean=0.7, sim_n=2000)])
    assert res.lam > 0.7 and res.width < 0.7 * res.real_width and res.lo <= 0.7 <= res.hi
    assert res.n_eff > 2 * res.n_ref


def test_an_anticorrelated_simulator_gets_no_weight():
    y = np.array([1.0, 0.0] * 15)
    res = predict([_stratum(y, 1 - y, sim_mean=0.5)])
    assert res.lam == 0 and res.width == res.real_width


def test_trials_for_width():
    y = np.array([1.0] * 15 + [0.0] * 15)
    with_sim, real_only = trials_for_width([_stratum(y, y, sim_mean=0.5, sim_n=5000)], 0.15)
    assert with_sim is not None and real_only is not None and with_sim < real_only
    assert wilson(real_only // 2, real_only).hi - wilson(real_only // 2, real_only).lo <= 0.15 + 1e-3


@pytest.mark.parametrize(
    "sc",
    [
        Scenario(0.5, 0.5, 0.9, 30),
        Scenario(0.9, 0.7, 1.0, 30),  # biased sim, perfectly correlated where the margins allow
        Scenario(0.1, 0.1, -0.5, 30),  # anti-correlated
        Scenario(0.5, 0.3, 0.9, 10),
        Scenario(0.5, 0.5, 0.0, 30),  # no information
        Scenario(0.5, 0.5, 0.9, 40, strata=4),
        Scenario(0.7, 0.5, 0.9, 40, paired=0.5),
    ],
    ids=Scenario.label,
)
def test_coverage_table(sc):
    m = run(sc, REPS, seed=3)
    assert m["coverage"] >= min(0.95, m["coverage_real"]) - SLACK, m
    assert m["width"] <= m["width_real"] + 0.005


def _toy_run(tmp_path: Path) -> Path:
    assert (
        main(
            [
                "run",
                "suite=tests.toy_suite:ToySuite",
                "policy=scripted",
                "episodes=8",
                "horizon=8",
                "workers=1",
                f"out={tmp_path}",
                "run_id=sim",
            ]
        )
        == 0
    )
    return tmp_path / "sim"


def _write(path: Path, rows: list[str], header: str = "cell,condition,seed,episode,success") -> Path:
    path.write_text("\n".join([header, *rows]) + "\n")
    return path


def test_cli_on_a_run_with_paired_and_unpaired_trials(tmp_path, capsys):
    sim = _toy_run(tmp_path)
    real = _write(
        tmp_path / "real.csv",
        [
            "reach/a/line,nominal,,0,0",
            "reach/a/line,,,1,1",
            "reach/a/line,nominal,3141116543,,1",
            "reach/b/line,,,,1",
            "reach/b/line,,,,0",
            "reach/b/line,nominal,,5,1",
        ],
    )
    out = tmp_path / "p.json"
    assert main(["predict", f"sim={sim}", f"real={real}", "width=0.3", f"out={out}"]) == 0
    doc = json.loads(out.read_text())
    assert doc["schema"] == "bench.predict/1" and doc["real_trials"] == {"paired": 4, "unpaired": 2}
    assert [s["key"] for s in doc["strata"]] == ["scripted/reach/a/line/nominal", "scripted/reach/b/line/nominal"]
    assert doc["target"]["real_trials_real_only"] >= doc["target"]["real_trials_with_sim"]
    assert "real only" in capsys.readouterr().out
    assert main(["predict", "--help"]) == 0 and "prediction-powered" in capsys.readouterr().out


@pytest.mark.parametrize(
    "rows, match",
    [
        (["reach/z/line,nominal,,,1"], r"row 1: cell 'reach/z/line' does not match the sim run .*reach/a/line"),
        (["reach/a/line,windy,,,1"], r"row 1: condition 'windy' does not match the sim run .*nominal"),
        (["reach/a/line,nominal,17,,1"], r"row 1: seed 17 has no sim episode in reach/a/line nominal"),
        (["reach/a/line,,,2,1", "reach/a/line,,,2,0"], r"row 2: episode 2 is already paired \(real=.* row 1\)"),
        (["reach/a/line,,,,2"], r"row 1: success='2'; expected 0 or 1"),
        ([",,,,1"], r"row 1: cell is missing; the sim has several"),
    ],
    ids=["unknown-cell", "unknown-condition", "unknown-seed", "twice-paired", "not-binary", "no-cell"],
)
def test_bad_real_tables(tmp_path, rows, match):
    sim = _toy_run(tmp_path)
    real = _write(tmp_path / "real.csv", rows)
    out = tmp_path / "p.json"
    with pytest.raises(DataError, match=match):
        predict_real(PredictConfig(sim=str(sim), real=str(real), out=str(out)))
    assert not out.exists()


def test_policy_mismatch_exits_2_and_writes_nothing(tmp_path, capsys):
    sim = _toy_run(tmp_path)
    capsys.readouterr()
    real = _write(tmp_path / "real.csv", ["octo,reach/a/line,1"], header="policy,cell,success")
    out = tmp_path / "p.json"
    assert main(["predict", f"sim={sim}", f"real={real}", f"out={out}"]) == 2
    err = capsys.readouterr().err
    assert (
        "policy 'octo' does not match the sim run" in err and "scripted" in err and len(err.strip().splitlines()) == 1
    )
    assert not out.exists()
    with pytest.raises(ConfigError, match="missing key 'real'"):
        predict_real(PredictConfig(sim=str(sim)))
    with pytest.raises(ConfigError, match="level='units' is not valid"):
        predict_real(PredictConfig(sim=str(sim), real=str(real), level="units"))


def test_simpler_tables():
    rel = SIMPLER.relative_to(REPO)
    doc = predict_real(PredictConfig(sim=str(REPO / rel / "sim.csv"), real=str(REPO / rel / "real.csv")))
    # aggregate rates: every stratum has its own real trials and none pairs with a sim episode
    assert doc["lambda"] == 0 and doc["estimate"] == doc["real_only"] and len(doc["strata"]) == 42
    assert doc["real_trials"] == {"paired": 0, "unpaired": 1572}
    m = simpler_units(15, 60)
    assert m["coverage"] >= 0.9 and m["width"] < m["width_real"]
