"""Sim-real agreement: statistics checked against hand computations, bootstrap, tables and CLI."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from scipy import stats

from bench.cli import main as bench_main
from bench.cli.correlate import main
from bench.core.errors import DataError
from bench.scoring.agreement import Outcome, _batch, agreement, load_outcomes, mmrv, point_estimates

# Four policies, 10 trials each.
#            sim          real
#   A   8/10 = 0.8    7/10 = 0.7
#   B   6/10 = 0.6    4/10 = 0.4
#   C   3/10 = 0.3    5/10 = 0.5
#   D   1/10 = 0.1    0/10 = 0.0
SIM = {"A": Outcome(10, 8), "B": Outcome(10, 6), "C": Outcome(10, 3), "D": Outcome(10, 1)}
REAL = {"A": Outcome(10, 7), "B": Outcome(10, 4), "C": Outcome(10, 5), "D": Outcome(10, 0)}
S = np.array([0.8, 0.6, 0.3, 0.1])
R = np.array([0.7, 0.4, 0.5, 0.0])


def test_pearson_by_hand():
    # means: sim 1.8/4 = 0.45, real 1.6/4 = 0.40
    # deviations: sim [.35, .15, -.15, -.35], real [.30, 0, .10, -.40]
    # sum of products = .105 + 0 - .015 + .140 = .230
    # sum of squares: sim .1225+.0225+.0225+.1225 = .29, real .09+0+.01+.16 = .26
    # r = .23 / sqrt(.29 * .26) = .23 / .274591 = 0.837611
    assert point_estimates(S, R)["pearson"] == pytest.approx(0.23 / math.sqrt(0.29 * 0.26), abs=1e-12)
    assert point_estimates(S, R)["pearson"] == pytest.approx(0.837611, abs=1e-6)


def test_spearman_by_hand():
    # ranks (1 = lowest): sim A4 B3 C2 D1, real A4 B2 C3 D1; d = [0, 1, -1, 0], sum d^2 = 2
    # rho = 1 - 6 * 2 / (4 * (16 - 1)) = 1 - 12/60 = 0.8
    assert point_estimates(S, R)["spearman"] == pytest.approx(0.8, abs=1e-12)


def test_kendall_by_hand():
    # 6 pairs: AB, AC, AD, BD, CD concordant; BC discordant (sim B > C, real B < C); no ties
    # tau = (5 - 1) / 6 = 2/3
    assert point_estimates(S, R)["kendall"] == pytest.approx(2 / 3, abs=1e-12)


def test_mmrv_by_hand_and_asymmetric():
    # Only the pair (B, C) is ordered differently. Charged the REAL gap |0.4 - 0.5| = 0.1
    # to both B and C: MMRV = (0 + 0.1 + 0.1 + 0) / 4 = 0.05.
    assert mmrv(sim=S, real=R) == pytest.approx(0.05, abs=1e-12)
    # Swapped, the charge is the SIM gap |0.6 - 0.3| = 0.3: (0.3 + 0.3) / 4 = 0.15.
    assert mmrv(sim=R, real=S) == pytest.approx(0.15, abs=1e-12)
    assert point_estimates(S, R)["mmrv"] == pytest.approx(0.05, abs=1e-12)


def test_mmrv_is_keyword_only_and_zero_when_ranks_agree():
    with pytest.raises(TypeError):
        mmrv(S, R)  # type: ignore[misc]
    assert mmrv(sim=[0.1, 0.5, 0.9], real=[0.2, 0.3, 0.8]) == 0.0


def test_mmrv_ties():
    # sim cannot tell the two apart but real can: (s0 < s1) = False != (r0 < r1) = True, charged
    # to policy 0 (the worse one on the real robot): |0.2 - 0.6| = 0.4; policy 1 is not charged.
    assert mmrv(sim=[0.5, 0.5], real=[0.2, 0.6]) == pytest.approx(0.2)
    # a real tie costs nothing, whatever sim says (the real gap is 0)
    assert mmrv(sim=[0.1, 0.9], real=[0.5, 0.5]) == 0.0


def test_batch_statistics_match_scipy():
    rng = np.random.default_rng(3)
    s = rng.integers(0, 11, (200, 5)) / 10  # ties included
    r = rng.integers(0, 11, (200, 5)) / 10
    for name, fn in (("pearson", stats.pearsonr), ("spearman", stats.spearmanr), ("kendall", stats.kendalltau)):
        got = _batch(name, s, r)
        for b in range(len(s)):
            if np.ptp(s[b]) == 0 or np.ptp(r[b]) == 0:
                assert np.isnan(got[b])
            else:
                assert got[b] == pytest.approx(fn(s[b], r[b])[0], abs=1e-9), (name, b)
    got = _batch("mmrv", s, r)
    for b in range(0, len(s), 17):
        assert got[b] == pytest.approx(mmrv(sim=s[b], real=r[b]))


def test_report_and_bootstrap():
    rep = agreement(SIM, REAL, n_boot=500, seed=0)
    st = rep["statistics"]
    assert st["pearson"]["value"] == pytest.approx(0.837611, abs=1e-6) and st["mmrv"]["value"] == pytest.approx(0.05)
    for _name, entry in st.items():
        lo, hi = entry["ci"]
        assert lo <= hi and entry["reason"] is None
        assert -1 <= lo and hi <= 1
    assert agreement(SIM, REAL, n_boot=500, seed=0) == rep  # seeded
    assert agreement(SIM, REAL, n_boot=500, seed=1)["statistics"] != st
    json.dumps(rep, allow_nan=False)


def _scaled(table: dict[str, Outcome], k: int) -> dict[str, Outcome]:
    return {p: Outcome(o.trials * k, o.successes * k) for p, o in table.items()}


def test_bootstrap_resamples_both_sides():
    width = lambda rep: rep["statistics"]["pearson"]["ci"][1] - rep["statistics"]["pearson"]["ci"][0]  # noqa: E731
    big = 100_000
    both_big = agreement(_scaled(SIM, big), _scaled(REAL, big), n_boot=300, seed=0)
    assert width(both_big) < 0.01  # same rates, almost no sampling noise
    assert both_big["statistics"]["pearson"]["ci"][0] < 0.837611 < both_big["statistics"]["pearson"]["ci"][1]
    assert width(agreement(SIM, _scaled(REAL, big), n_boot=300, seed=0)) > 0.1  # sim's 10 trials still count
    assert width(agreement(_scaled(SIM, big), REAL, n_boot=300, seed=0)) > 0.1  # and real's


def test_undefined_correlation_is_null_with_reason():
    sim = {p: Outcome(10, 5) for p in "ABC"}
    real = {"A": Outcome(10, 2), "B": Outcome(10, 5), "C": Outcome(10, 9)}
    rep = agreement(sim, real, n_boot=200, seed=0)
    for name in ("pearson", "spearman", "kendall"):
        assert rep["statistics"][name]["value"] is None
        assert "same sim success rate" in rep["statistics"][name]["reason"]
    # sim ranks nobody apart, so every real difference is a violation charged to the worse policy
    # (s_i < s_j is False, r_i < r_j is True): A max(.3, .7) = .7, B .4, C 0 -> 1.1 / 3
    assert rep["statistics"]["mmrv"]["value"] == pytest.approx(1.1 / 3)
    text = json.dumps(rep, allow_nan=False)
    assert "NaN" not in text
    every = agreement({p: Outcome(10, 10) for p in "AB"}, {p: Outcome(10, 0) for p in "AB"}, n_boot=50)
    assert every["statistics"]["pearson"]["ci"] is None
    assert "same sim and real success rate" in every["statistics"]["pearson"]["reason"]


# ----------------------------------------------------------------------------- tables


def test_load_formats(tmp_path):
    rows = [{"policy": p, "trials": o.trials, "successes": o.successes} for p, o in SIM.items()]
    (tmp_path / "a.json").write_text(json.dumps(rows))
    (tmp_path / "b.json").write_text(json.dumps({"policies": rows}))
    (tmp_path / "c.json").write_text(
        json.dumps({r["policy"]: {"trials": r["trials"], "successes": r["successes"]} for r in rows})
    )
    (tmp_path / "d.csv").write_text(
        "policy,trials,successes\n" + "".join(f"{r['policy']},{r['trials']},{r['successes']}\n" for r in rows)
    )
    for name in ("a.json", "b.json", "c.json", "d.csv"):
        assert load_outcomes(tmp_path / name) == SIM


@pytest.mark.parametrize(
    "text, pattern",
    [
        ("policy,trials,successes\nA,10,11\n", "row 0: field 'successes' is 11 > trials 10 for policy 'A'"),
        ("policy,trials,successes\nA,0,0\n", "field 'trials' is 0 for policy 'A'"),
        ("policy,trials,successes\nA,10,2.5\n", "field 'successes' is '2.5'; expected a non-negative integer"),
        ("policy,trials\nA,10\n", "row 0: field 'successes' is missing"),
        ("policy,trials,successes\nA,10,2\nA,10,3\n", "row 1: policy 'A' appears twice"),
    ],
    ids=["too-many", "no-trials", "fraction", "missing", "duplicate"],
)
def test_bad_tables(tmp_path, text, pattern):
    (tmp_path / "t.csv").write_text(text)
    with pytest.raises(DataError, match=pattern) as err:
        load_outcomes(tmp_path / "t.csv")
    assert "\n" not in str(err.value) and str(err.value).startswith(str(tmp_path / "t.csv"))


def test_unknown_policy_is_one_line_error():
    real = dict(REAL)
    real["E"] = real.pop("D")
    with pytest.raises(DataError, match="real: policy 'D' is in sim but not here") as err:
        agreement(SIM, real, n_boot=10)
    assert "\n" not in str(err.value)


# ----------------------------------------------------------------------------- CLI


def _write(tmp_path, name, table):
    path = tmp_path / name
    path.write_text(json.dumps([{"policy": p, "trials": o.trials, "successes": o.successes} for p, o in table.items()]))
    return path


def test_cli_table_and_json(tmp_path, capsys):
    sim, real = _write(tmp_path, "sim.json", SIM), _write(tmp_path, "real.json", REAL)
    out = tmp_path / "out" / "agreement.json"
    assert bench_main(["correlate", f"sim={sim}", f"real={real}", "n_boot=300", "seed=2", f"out={out}"]) == 0
    text = capsys.readouterr().out
    assert "pearson" in text and "0.838" in text and "mmrv" in text and "0.050" in text
    doc = json.loads(out.read_text())
    assert doc["n_boot"] == 300 and doc["seed"] == 2 and doc["statistics"]["kendall"]["value"] == pytest.approx(2 / 3)


def test_cli_null_in_json(tmp_path):
    sim = _write(tmp_path, "sim.json", {p: Outcome(4, 2) for p in "AB"})
    real = _write(tmp_path, "real.json", {"A": Outcome(4, 1), "B": Outcome(4, 3)})
    out = tmp_path / "a.json"
    assert main([f"sim={sim}", f"real={real}", "n_boot=50", f"out={out}"]) == 0
    text = out.read_text()
    assert "NaN" not in text and json.loads(text)["statistics"]["pearson"]["value"] is None


def test_cli_errors(tmp_path, capsys):
    sim, real = (
        _write(tmp_path, "sim.json", SIM),
        _write(tmp_path, "real.json", {"A": Outcome(3, 1), "B": Outcome(3, 2)}),
    )
    assert bench_main(["correlate", f"sim={sim}", f"real={real}"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "policy 'C' is in" in err
    assert bench_main(["correlate", f"sim={sim}", f"reel={real}"]) == 2
    assert "unknown key 'reel'" in capsys.readouterr().err
    assert bench_main(["correlate", "--help"]) == 0
    assert "MMRV weights each rank violation by the REAL gap" in capsys.readouterr().out
