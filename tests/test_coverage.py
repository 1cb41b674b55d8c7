"""Coverage metrics on hand-made data with known answers, the slope fit on synthetic numbers,
`bench coverage` end to end on small datasets, the sweep's argument checks and its plot."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from baselines import coverage_sweep as sweep
from bench.cli import coverage as cov
from bench.core.errors import ConfigError
from bench.logs import from_arrays, write_dataset
from bench.protocols.suite import Cell
from bench.scoring import coverage as covm
from bench.scoring import trend
from bench.sims.perturb.axes import conditions_from_config

CELLS = [
    Cell("s", "Lift", "Panda", "default", "seen"),
    Cell("s", "Lift", "Sawyer", "default", "seen"),
    Cell("s", "Lift", "UR5e", "default", "unseen"),
    Cell("s", "Lift", "Jaco", "default", "unseen"),
]
MANIFEST = {"robots": {"seen": ["Panda", "Sawyer"], "unseen": ["UR5e", "Jaco"]}}


def _meta(robot: str, **kw) -> dict:
    return {"task": "Lift", "robot": robot, "env": "default", "condition": "nominal", "params": {}, **kw}


# -- support ---------------------------------------------------------------------------------
def test_support_counts_present_vs_evaluated_per_split():
    s = covm.support([_meta("Panda"), _meta("Panda"), _meta("UR5e")], CELLS, MANIFEST)
    r = s["robots"]
    assert r["covered"] == ["Panda", "UR5e"] and r["missing"] == ["Jaco", "Sawyer"] and r["fraction"] == 0.5
    assert r["by_split"]["seen"]["covered"] == ["Panda"] and r["by_split"]["unseen"]["fraction"] == 0.5
    assert r["episodes"] == {"Panda": 2, "UR5e": 1}
    assert r["unseen_in_training"] == ["UR5e"]  # held-out robot leaked into the training data
    assert s["tasks"]["fraction"] == 1.0 and s["envs"]["covered"] == ["default"]
    assert s["cells"] == {
        "evaluated": 4,
        "covered": 2,
        "fraction": 0.5,
        "missing": ["Lift/Sawyer/default", "Lift/Jaco/default"],
    }


# -- state coverage --------------------------------------------------------------------------
def test_state_coverage_known_distances_and_radius():
    train = np.array([[0, 0], [1, 0], [0, 1], [1, 1]], float)  # std 0.5 per dim
    episode = np.array([0, 0, 1, 1])
    ev = np.array([[0, 0], [3, 0]], float)
    out = covm.state_coverage(train, episode, ev, ["a", "b"])
    # [3,0] -> nearest [1,0]: (2/0.5, 0) -> RMS 4/sqrt(2); training first states are 1/0.5 apart -> sqrt(2)
    assert out["distances"] == pytest.approx([0.0, 4 / np.sqrt(2)], abs=1e-6)
    assert out["reference_radius"] == pytest.approx(np.sqrt(2), abs=1e-6)
    assert out["overall"]["covered"] == 0.5
    assert out["groups"]["a"]["covered"] == 1.0 and out["groups"]["b"]["covered"] == 0.0


def test_leave_one_episode_out_looks_past_the_episodes_own_frames():
    # episode 0: 200 frames within 1e-3 of the origin; its nearest other-episode state is 2 away
    rng = np.random.default_rng(0)
    train = np.concatenate([rng.normal(scale=1e-3, size=(200, 3)), np.full((5, 3), 2.0), np.full((5, 3), -2.0)])
    episode = np.repeat([0, 1, 2], [200, 5, 5])
    out = covm.state_coverage(train, episode, np.zeros((1, 3)), scale=np.ones(3))
    assert out["reference"]["n"] == 3
    assert out["reference"]["max"] == pytest.approx(np.sqrt(12) / np.sqrt(3), rel=1e-2)  # -2 -> +2 per dim
    assert out["reference"]["mean"] > 1.9  # no episode is "covered" by its own frames


def test_single_episode_has_no_radius_but_distances():
    out = covm.state_coverage(np.zeros((3, 2)), np.zeros(3), np.ones((2, 2)))
    assert out["reference_radius"] is None and out["overall"]["covered"] is None
    assert "fewer than 2 episodes" in out["overall"]["reason"] and out["overall"]["mean"] > 0


# -- parameter ranges -------------------------------------------------------------------------
def test_param_coverage_of_ranges_grids_and_nominal():
    conds = conditions_from_config({"gain": ["uniform(0.7,1.3)"], "latency": [2, 4]})
    train = [{"gain": 0.9}, {"gain": 1.1}, {}, {}]  # {} = ran at the nominal level
    out = covm.param_coverage(train, conds)
    g = out["gain"]
    assert g["evaluated"] == [0.7, 1.3] and g["training"] == [0.9, 1.1]
    assert g["coverage"] == pytest.approx(0.2 / 0.6, abs=1e-6)
    assert g["coverage_log"] == pytest.approx(np.log(1.1 / 0.9) / np.log(1.3 / 0.7), abs=1e-6)
    lat = out["latency"]  # nominal 0 plus levels 2, 4; training never left 0
    assert lat["evaluated"] == [0.0, 4.0] and lat["coverage"] == 0.0 and lat["levels_inside"] == pytest.approx(1 / 3)
    assert "coverage_log" not in lat


# -- slope ------------------------------------------------------------------------------------
def test_wls_slope_recovers_a_line_and_weights_matter():
    assert trend.wls_slope([0, 1, 2], [1, 3, 5], [1, 1, 1]) == pytest.approx((2.0, 1.0))
    # a noisy outlier with a huge variance barely moves the fit
    b, _ = trend.wls_slope([0, 1, 2, 3], [0, 1, 2, 30], [1, 1, 1, 1e6])
    assert b == pytest.approx(1.0, abs=0.01)
    with pytest.raises(ValueError):
        trend.wls_slope([1, 1], [0, 1], [1, 1])


def _outcomes(p: float, n: int, rng) -> np.ndarray:
    return (rng.random(n) < p).astype(float)


def _series(rates, seeds=1, n=200, cells=("a", "b"), seed=0):
    """Points -> seeds -> {cell: outcomes}; rates[k] is point k's rate (or a list of one rate per seed)."""
    rng = np.random.default_rng(seed)
    pts = []
    for r in rates:
        per_seed = r if isinstance(r, (list, tuple)) else [r] * seeds
        pts.append([{c: _outcomes(p, n, rng) for c in cells} for p in per_seed])
    return pts


def _slope(pts, x, seed=1, n_boot=500):
    boot = trend.SeriesBootstrap(pts, np.random.default_rng(seed), n_boot)
    means = [boot.mean(k, ["a", "b"]) for k in range(len(pts))]
    n = [sum(len(v) for s in pt for v in s.values()) for pt in pts]
    return trend.slope_with_interval(x, [m[0] for m in means], [m[1] for m in means], n)


def test_slope_interval_covers_a_real_trend_and_zero_for_none():
    s = _slope(_series([0.2, 0.5, 0.8]), [1, 2, 3])
    assert s["ci"][0] < 0.3 < s["ci"][1] and s["ci"][0] > 0.15
    s = _slope(_series([0.5, 0.5, 0.5], n=100, seed=3), [1, 2, 3])
    assert s["ci"][0] < 0 < s["ci"][1]
    assert trend.slope_with_interval([1, 1], [0.2, 0.3], [np.zeros(3), np.zeros(3)], [10, 10])["value"] is None


def test_training_seed_spread_widens_the_interval():
    # same pooled rate (0.5), but one point's seeds disagree (0.1 vs 0.9): its interval must be far wider
    calm = trend.SeriesBootstrap(_series([0.5], seeds=2), np.random.default_rng(0), 1000)
    split = trend.SeriesBootstrap(_series([[0.1, 0.9]]), np.random.default_rng(0), 1000)
    (_, r1), (_, r2) = calm.mean(0, ["a", "b"]), split.mean(0, ["a", "b"])
    w1, w2 = np.ptp(calm.interval(r1)), np.ptp(split.interval(r2))
    assert w2 > 4 * w1 and calm.interval(r1)[0] < 0.5 < calm.interval(r1)[1]


def test_episodes_are_paired_across_points():
    # two points with identical outcomes: every replicate of their difference is exactly 0
    pts = _series([0.4], seeds=1)
    boot = trend.SeriesBootstrap([pts[0], pts[0]], np.random.default_rng(0), 300)
    (a, ra), (b, rb) = boot.mean(0, ["a"]), boot.mean(1, ["a"])
    assert a == b and np.all(ra == rb) and np.ptp(ra) > 0


def test_bootstrap_is_reproducible_from_the_seed_and_skips_missing_cells():
    pts = _series([0.3, 0.6], seeds=2, n=10)
    a = _slope(pts, [0, 1], seed=7)
    assert a == _slope(pts, [0, 1], seed=7)
    boot = trend.SeriesBootstrap(pts, np.random.default_rng(0), 100)
    assert boot.mean(0, ["nope"]) == (None, None)
    assert boot.estimate(None, None)["reason"] == "no completed episodes"


# -- bench coverage on small datasets ------------------------------------------------------------
def _dataset(root: Path, episodes: list[tuple[str, np.ndarray, dict]]) -> Path:
    eps = [{"observation.state": s, "action": np.zeros((len(s), 1), np.float32)} for _, s, _ in episodes]
    meta = [_meta(r, **m) for r, _, m in episodes]
    tasks = [f"Lift/{r}/default" for r, _, _ in episodes]
    return write_dataset(root, from_arrays(eps, fps=20, task=tasks, meta=meta))


def test_cli_writes_the_report_with_known_values(tmp_path: Path, capsys):
    base = np.zeros((4, 2), np.float32)
    train = _dataset(
        tmp_path / "train",
        [
            ("Panda", base, {"params": {"gain": 0.9}}),
            ("Panda", base + [0, 1], {"params": {"gain": 1.1}}),
            ("Sawyer", base + [1, 0], {}),
        ],
    )
    # evaluation: Panda starts where training did; UR5e starts far away
    ev = _dataset(tmp_path / "eval", [("Panda", base, {}), ("UR5e", base + [5, 5], {})])
    out = tmp_path / "cov.json"
    rc = cov.main(
        [f"data={train}", "suite=held_out_robots", f"eval_data={ev}", "perturb.gain=uniform(0.5,1.5)", f"out={out}"]
    )
    assert rc == 0
    doc = json.loads(out.read_text())
    assert doc["support"]["robots"]["covered"] == ["Panda", "Sawyer"]
    assert doc["support"]["robots"]["by_split"]["unseen"]["fraction"] == 0.0
    assert doc["state"]["groups"]["Lift/Panda/default"]["covered"] == 1.0
    assert doc["state"]["groups"]["Lift/UR5e/default"]["covered"] == 0.0
    assert doc["state"]["splits"]["unseen"]["n"] == 1
    assert doc["params"]["gain"]["coverage"] == pytest.approx(0.2)
    assert "state coverage" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv, match",
    [
        (["suite=held_out_robots"], "data: give the training dataset"),
        (["data=/nonexistent", "eval_data=/nonexistent"], "eval_data='/nonexistent': not a dataset folder"),
        (["data=x", "quantil=0.9"], "Did you mean 'quantile'"),
        (["data=x", "robots=[UR5]"], "Did you mean 'UR5e'"),
        (["data=x", "quantile=1.5"], "quantile=1.5: must be in"),
        (["sweep"], "the coverage sweep is an experiment script now: python -m baselines.coverage_sweep"),
    ],
)
def test_bad_input_is_a_one_line_error(argv, match):
    with pytest.raises(ConfigError, match=match):
        cov.main(argv)


@pytest.mark.parametrize(
    "argv, match",
    [
        (["parts=[robot]"], "Did you mean 'robots'"),
        (["order=[Panda,UR5e]"], "'UR5e' is not a seen robot"),
        (["dr_axis=latency"], "DR widths are scales of nominal"),
        (["dr_widths=[1.5]"], r"must be in \(0, 1\)"),
        (["surrogate_perturb=latency"], "write AXIS=LEVEL"),
        (["surrogate_perturb=lateny=4"], "Did you mean 'latency'"),
        (["bc.epoch=3"], "Did you mean 'epochs'"),
        (["budget=half"], "valid: fixed, per_robot"),
        (["seeds=[1,1]"], "distinct training seeds"),
    ],
)
def test_sweep_arguments_are_checked_before_any_work(argv, match, tmp_path: Path):
    with pytest.raises(ConfigError, match=match):
        sweep.main([f"workdir={tmp_path / 'w'}", f"out={tmp_path / 'o'}", *argv])
    assert not (tmp_path / "w").exists() and not (tmp_path / "o").exists()


def test_help_lists_keys():
    assert "eval_data" in cov.help_text() and "reference radius" in cov.help_text()
    assert "surrogate_perturb" in sweep.sweep_help() and "total_episodes" in sweep.sweep_help()


def _point(name, x, held, ind):
    est = lambda v: {"value": v, "ci": [max(0, v - 0.1), min(1, v + 0.1)]}  # noqa: E731
    return {
        "name": name,
        "x": x,
        "train_robots": ["Panda"],
        "held_out": est(held),
        "in_distribution": est(ind),
        "gap": {"value": ind - held, "ci": [ind - held - 0.2, ind - held + 0.2]},
        "training": {"episodes": 10, "train_wall_s": 1.0},
        "coverage": {"state_unseen_covered": 0.5},
    }


def test_plot_and_table_render_a_sweep_document(tmp_path: Path):
    slope = {"value": 0.1, "ci": [0.0, 0.2], "intercept": 0.2}
    doc = {
        "confidence": 0.95,
        "robots": {
            "x_label": "robots",
            "points": [_point("robots1", 1, 0.3, 0.9), _point("robots2", 2, 0.4, 0.9)],
            "held_out_slope": slope,
            "gap_slope": slope,
        },
        "surrogate": {
            "target": "Lift/Panda/default",
            "in_domain_episodes": 12,
            "surrogate_episodes": 24,
            "variants": {
                "in_domain": {"training": {"episodes": 12}, "success": {"value": 0.5, "ci": [0.3, 0.7]}},
                "plus_other_robots": {
                    "training": {"episodes": 36},
                    "success": {"value": 0.6, "ci": [0.4, 0.8]},
                    "vs_in_domain": {"value": 0.1, "ci": [-0.1, 0.3], "verdict": "no detectable effect"},
                },
            },
        },
    }
    path = sweep.plot_sweep(doc, tmp_path / "s.png")
    assert path.stat().st_size > 10_000 and path.read_bytes()[:4] == b"\x89PNG"
    from rich.console import Console

    console = Console(record=True, width=200)
    sweep.render_sweep(doc, console)
    text = console.export_text()
    assert "+0.100 [+0.000, +0.200]" in text and "no detectable effect" in text


def test_initial_states_use_the_runs_episode_seeds():
    from bench.protocols.suite import episode_seed

    class Env:
        def reset(self, seed):
            return {"state": np.array([seed % 1000, 1.0])}

        def close(self):
            self.closed = True

    class Suite:
        default_horizon = 10

        def make_env(self, cell, horizon):
            return Env()

    states, groups = covm.initial_states_from_suite(Suite(), CELLS[:2], seed=3, episodes=2)
    assert groups == ["Lift/Panda/default"] * 2 + ["Lift/Sawyer/default"] * 2
    assert states[:, 0].tolist() == [episode_seed(3, i) % 1000 for i in (0, 1)] * 2


def test_sweep_selects_the_first_episodes_across_sources(tmp_path: Path):
    s = np.zeros((3, 2), np.float32)
    a = _dataset(tmp_path / "a", [("Panda", s, {}), ("Panda", s, {"success_once": False}), ("Sawyer", s, {})])
    b = _dataset(
        tmp_path / "b", [("Panda", s + 1, {}), ("Panda", s + 2, {"condition": "gain=2", "success_once": False})]
    )
    d = sweep._select([a, b], [("Panda", "nominal", 2), ("Sawyer", "nominal", 1)])
    assert [(Path(e["source"]).name, e["index"]) for e in d.episodes] == [("a", 0), ("b", 0), ("a", 2)]
    # under a perturbation failed demonstrations are kept (no truncation of the randomised range)
    assert [e["index"] for e in sweep._select([a, b], [("Panda", "gain=2", 1)]).episodes] == [1]
    with pytest.raises(Exception, match="only 2 usable Panda demonstrations under nominal, 3 wanted"):
        sweep._select([a, b], [("Panda", "nominal", 3)])


@pytest.mark.slow
def test_tiny_sweep_end_to_end(tmp_path: Path):
    """Every part on real robosuite at a toy budget (minutes): records, trains, evaluates, writes JSON + PNG."""
    out = tmp_path / "out"
    argv = [
        "order=[Panda,Sawyer]",
        "total_episodes=2",
        "eval_episodes=1",
        "horizon=30",
        "dr_widths=[0.3]",
        "surrogate_in_domain=1",
        "surrogate_episodes=1",
        "surrogate_eval_episodes=2",
        "bc.successful_only=false",
        "bc.epochs=1",
        "workers=1",
        "n_boot=200",
        f"workdir={tmp_path / 'work'}",
        f"out={out}",
    ]
    assert sweep.main(argv + ["seeds=[0,1]"]) == 0
    doc = json.loads((out / "sweep.json").read_text())
    assert [p["name"] for p in doc["robots"]["points"]] == ["robots1", "robots2"]
    assert [p["x"] for p in doc["dr"]["points"]] == [0.0, 0.3]
    assert set(doc["surrogate"]["variants"]) == {"in_domain", "plus_other_robots", "plus_perturbed_sim"}
    assert all(len(p["cells"]) == 7 for p in doc["robots"]["points"])
    assert (out / "sweep.png").stat().st_size > 10_000
    assert doc["robots"]["points"][0]["cells"]["Lift/Panda/default"]["n"] == 2  # 1 episode x 2 training seeds
    assert sweep.main(argv + ["seeds=[0,1]"]) == 0  # a rerun reuses every artifact and scores the same
    again = json.loads((out / "sweep.json").read_text())
    assert again["robots"] == doc["robots"] and again["surrogate"] == doc["surrogate"]
