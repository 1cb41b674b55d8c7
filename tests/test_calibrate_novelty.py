"""Held-out data that is new (bench.calibrate.novelty) in the forward calibration: the measures themselves, the
spec keys that place the held-out data, the `heldout` and `trust` sections, and the repeat baseline."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest
import yaml

from bench.calibrate import generate, novelty
from bench.calibrate.data import extract
from bench.calibrate.generate import declared_files, simulate_arm, spec_dict, write_case
from bench.calibrate.spec import load_spec, parse_spec
from bench.calibrate.trace import calibrate_episodes
from bench.cli import main
from bench.core.errors import DataError, SpecError

FPS = 100.0


def _periodic(t: np.ndarray, period: float, seed: int = 0) -> np.ndarray:
    """Two channels of three harmonics of 1 / period with seeded phases: (T, 4) positions and their rates."""
    rng = np.random.default_rng(seed)
    w = 2 * np.pi * np.arange(1, 4) / period
    cols = []
    for _ in range(2):
        ph = rng.uniform(0, 2 * np.pi, 3)
        cols += [
            np.sin(w[:, None] * t + ph[:, None]).sum(0),
            (w[:, None] * np.cos(w[:, None] * t + ph[:, None])).sum(0),
        ]
    return np.stack(cols, axis=1)


# --- the measures ------------------------------------------------------------------------------------------
def test_period_of_a_sine_is_found():
    t = np.arange(0, 10, 1 / FPS)
    x = np.stack([np.sin(2 * np.pi * t / 2.5), np.cos(2 * np.pi * t / 2.5)], axis=1)
    period, r = novelty.period_of(x, FPS)
    assert period == pytest.approx(2.5, abs=0.02) and r > 0.99


def test_a_random_walk_has_no_period():
    x = np.cumsum(np.random.default_rng(0).standard_normal((2000, 2)), axis=0)
    assert novelty.period_of(x, FPS)[0] is None


def test_least_repeated_window_is_the_stretch_seen_once():
    """1.5 periods: the last half period repeats the first; the middle half period is seen only once."""
    period = 2.0
    x = _periodic(np.arange(0, 1.5 * period, 1 / FPS), period)
    n, length = len(x), int(0.3 * len(x))
    start, stop, share = novelty.least_repeated_window(x, length, 0)
    assert 0.5 * period * FPS - 1 <= start and stop <= period * FPS + 1, (start, stop)
    assert share < 0.05
    end = novelty.repeat_share(novelty.nearest(x[: n - length], x[n - length :], novelty.spread(x))[0])
    assert end > 0.95  # the plain time split holds out a repeat


def test_identical_data_repeat_entirely():
    x = np.random.default_rng(1).standard_normal((300, 4))
    assert novelty.repeat_share(novelty.nearest(x, x, novelty.spread(x))[0]) == 1.0


def test_banded_choice_keeps_the_seeded_split_when_every_episode_is_new():
    rng = np.random.default_rng(2)
    xs = [rng.standard_normal((200, 4)) + 10 * i for i in range(5)]  # nothing repeats across episodes
    seeded = sorted(np.random.default_rng(0).permutation(5)[:2].tolist())
    assert sorted(novelty.least_repeated_episodes(xs, 2, 0)) == seeded
    xs[seeded[0]] = xs[(seeded[0] + 1) % 5].copy()  # now an exact repeat of another episode: not held out
    assert seeded[0] not in novelty.least_repeated_episodes(xs, 2, 0)


# --- spec keys ---------------------------------------------------------------------------------------------
def _raw(**extra):
    return {**spec_dict(None, model_file=str(generate.ARM)), **extra}


def test_spec_keys_parse_and_round_trip():
    spec = parse_spec(_raw(holdout=[1.0, 2.5], holdout_at="end", period=2.0))
    assert (spec.holdout_window, spec.holdout_at, spec.period) == ((1.0, 2.5), "end", 2.0)
    doc = spec.to_json()
    assert doc["holdout"] == [1.0, 2.5] and doc["holdout_at"] == "end" and doc["period"] == 2.0
    again = parse_spec({k: v for k, v in doc.items() if k != "source"})
    assert (again.holdout_window, again.holdout_at, again.period) == ((1.0, 2.5), "end", 2.0)
    default = parse_spec(_raw())
    assert (default.holdout, default.holdout_window, default.holdout_at, default.period) == (
        0.3,
        None,
        "least_repeated",
        None,
    )


BAD_SPECS = [
    ({"holdout": [1.0]}, r"spec field 'holdout' must be a share \(0.05-0.9\) or a window"),
    ({"holdout": [2.0, 1.0]}, r"spec field 'holdout': the window \[2, 1\] s is empty"),
    ({"holdout": 2}, r"spec field 'holdout' must be a number in"),
    ({"holdout_at": "middle"}, r"spec field 'holdout_at': 'middle'; valid: least_repeated, end, episodes"),
    ({"period": -1}, r"spec field 'period' must be a number in"),
]


@pytest.mark.parametrize("extra, pattern", BAD_SPECS, ids=["short", "empty", "share", "at", "period"])
def test_bad_spec_keys_are_one_line_naming_the_field(extra, pattern):
    with pytest.raises(SpecError, match=pattern) as exc:
        parse_spec(_raw(**extra))
    assert "\n" not in str(exc.value)


@pytest.fixture(scope="module")
def short_log():
    return simulate_arm(None, episodes=2, duration=1.0, seed=0)[0]


BAD_SPLITS = [
    (
        {"holdout": [0.2, 0.4]},
        SpecError,
        r"spec field 'holdout': a time window needs a one-episode log; this one has 2",
    ),
    ({"period": 5.0}, DataError, r"less than one period of its excitation \(spec field 'period': 5 s\)"),
]


@pytest.mark.parametrize("extra, error, pattern", BAD_SPLITS, ids=["window-of-many", "period"])
def test_bad_splits_are_one_line_naming_the_field(short_log, extra, error, pattern):
    with pytest.raises(error, match=pattern) as exc:
        extract(parse_spec(_raw(**extra)), short_log, FPS, nq=3, nv=3, nu=3)
    assert "\n" not in str(exc.value)


def test_a_window_that_leaves_nothing_to_fit_is_refused(short_log):
    with pytest.raises(
        SpecError,
        match=r"spec field 'holdout': holding out 0-0.99 s of a 0.99 s log \(guards of 0 samples\) leaves 0 samples to fit",
    ):
        extract(parse_spec(_raw(holdout=[0.0, 5.0])), short_log[:1], FPS, nq=3, nv=3, nu=3)
    rec = extract(parse_spec(_raw(holdout=[0.3, 0.6])), short_log[:1], FPS, nq=3, nv=3, nu=3)
    assert [(w.start, w.stop) for w in rec.train] == [(0, 30), (60, 100)] and rec.holdout[0].start == 30
    assert rec.heldout.placement == "window"


# --- the forward calibration -------------------------------------------------------------------------------
def test_forward_calibration_reports_heldout_trust_and_beats_memory(tmp_path, capsys):
    case = write_case(tmp_path / "case", "bias", episodes=3, duration=2.0, seed=1)
    out = tmp_path / "out"
    argv = [f"spec={case / 'spec.yaml'}", f"logs={case / 'logs'}", f"out={out}", "effects=[bias]", "residual=false"]
    assert main(["calibrate", *argv]) == 0
    err = capsys.readouterr().err
    assert re.search(r"held out: .*% of it repeats fitted states", err)
    assert re.search(r"k-step [0-9.e-]+ against [0-9.e-]+ for the repeat baseline \(beats it\)", err)
    doc = json.loads((out / "calibration.json").read_text())
    held, trust, repeat = doc["heldout"], doc["trust"], doc["repeat_baseline"]
    assert held["placement"] == "least_repeated" and 0 <= held["repeat_share"] < 0.5 and not held["nothing_new"]
    assert [w["episode"] for w in held["windows"]] == [w["episode"] for w in doc["data"]["holdout"]]
    assert trust["heldout"] == held
    assert trust["beats_repeat"] is True and trust["simulates_better"] is True
    assert trust["repeat_baseline_nrmse"] == repeat["k_step_nrmse"] == repeat[repeat["best"]]["k_step_nrmse"]
    assert doc["errors"]["final"]["k_step_nrmse"] < 0.2 * repeat["k_step_nrmse"]
    fw = trust["forward"]
    assert fw["declared"] == doc["errors"]["nominal"]["free_run_nrmse"]
    assert fw["calibrated"] == doc["errors"]["final"]["free_run_nrmse"] and fw["rose"] == []
    assert doc["spec"]["holdout_at"] == "least_repeated"
    report = (out / "report.md").read_text()
    assert "## How far the held-out errors can be trusted" in report and "The final model" in report
    head = report.split("\n## ", 1)[0]  # the verdict comes before every section and table
    assert "|" not in head and "**Verdict.** The calibrated model simulates the held-out data better than" in head
    assert "for the repeat baseline (beats it). Effects added: bias@" in head


def _periodic_multisine(period: float):
    """generate's reference, made periodic: harmonics of 1 / period (no fade-in), starting at 0."""

    def multisine(rng, t, amp, n=5):
        w = 2 * np.pi * np.arange(1, 4) / period
        a = rng.uniform(-1, 1, 3)
        s = (a[:, None] * (1 - np.cos(w[:, None] * t))).sum(0)  # at rest at 0 when t = 0, as the arm starts
        ds = (a[:, None] * w[:, None] * np.sin(w[:, None] * t)).sum(0)
        scale = amp / np.abs(s).max()
        return scale * s, scale * ds

    return multisine


def test_a_periodic_log_holds_out_its_least_repeated_stretch(tmp_path, monkeypatch):
    """One episode of 1.75 periods (the arm settles onto its periodic path in about half a second): the end split
    would hold out a repeat of the first period; the default holds out a stretch seen only once (the fitted data
    lie before and after it)."""
    period = 2.0
    monkeypatch.setattr(generate, "_multisine", _periodic_multisine(period))
    episodes, _ = simulate_arm("bias", episodes=1, duration=1.75 * period, seed=0)
    spec = load_spec(declared_files(tmp_path, "bias"))
    end = extract(
        parse_spec({**yaml.safe_load(spec.source.read_text()), "holdout_at": "end"}, tmp_path),
        episodes,
        FPS,
        nq=3,
        nv=3,
        nu=3,
    )
    assert end.heldout.placement == "end" and end.heldout.repeat_share > 0.6 and end.heldout.nothing_new
    cal = calibrate_episodes(spec, episodes, FPS, effects=(), residual=False)
    held = cal.heldout
    assert held is not None and held.placement == "least_repeated"
    assert held.period_s == pytest.approx(period, abs=0.05) and held.period_source == "detected"
    assert held.repeat_share < 0.1 and held.end_share == pytest.approx(end.heldout.repeat_share)
    (w,) = held.windows
    assert 0.5 * period <= w["start_s"] and w["stop_s"] <= 1.5 * period  # not the stretch that repeats the first
    rec = cal.rec
    assert len(rec.train) == 2 and rec.train[0].stop == rec.holdout[0].start == round(w["start_s"] * FPS)
    rep = cal.errors["repeat"]
    assert 0 < rep["period"]["covered_share"] < 1  # one period before the window's start is before the log
    assert cal.trust["repeat_baseline_nrmse"] == rep["k_step_nrmse"]
    assert not any("NOTHING NEW" in x for x in cal.warnings)
