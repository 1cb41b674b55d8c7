"""`bench logs card`: N_eff = N (1 - d) (1 - n) (1 - c) on logs whose answer is known; `bench logs rank`
on a spec calibration; bad input is one line, exit 2, nothing written."""

import json
import re

import numpy as np
import pytest

from bench.cli import main
from bench.logs import from_arrays, write_dataset
from bench.logs.card import card, noise_share
from tests.fixtures import calibrated


def _episodes(n: int, noise: float = 0.0, seed: int = 0) -> list[dict]:
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 4, 200)
    out = []
    for i in range(n):
        x = np.stack([np.sin(t * (1 + 0.3 * i)), np.cos(t * (0.5 + 0.2 * i))], axis=1)
        x = x + rng.normal(0, noise, x.shape)
        out.append({"observation.state": x.astype(np.float32), "action": np.zeros((200, 1), np.float32)})
    return out


def test_near_duplicates_are_counted_once():
    eps = _episodes(4)
    eps.append({k: v + np.float32(1e-4) for k, v in eps[1].items()})  # a replay of episode 1
    doc = card(from_arrays(eps, fps=50))
    assert doc["N"] == 5 and doc["d"] == pytest.approx(0.2)
    assert doc["duplicates"] == [{"episode": 4, "of": 1, "distance": pytest.approx(doc["duplicates"][0]["distance"])}]
    assert doc["N_eff"] == pytest.approx(5 * 0.8 * (1 - doc["n"]))


def test_noise_share_matches_the_noise_put_in():
    clean = [e["observation.state"].astype(float) for e in _episodes(6)]
    noisy = [e["observation.state"].astype(float) for e in _episodes(6, noise=0.3, seed=1)]
    n_clean, _ = noise_share(clean)
    n_noisy, per = noise_share(noisy)
    assert n_clean < 1e-3
    expected = 0.09 / np.concatenate(noisy).var(axis=0)  # sigma^2 / total variance, per channel
    assert per == pytest.approx(expected, rel=0.15)
    assert n_noisy == pytest.approx(expected.mean(), rel=0.15)


def test_card_cli_and_json(tmp_path, capsys):
    logs = write_dataset(tmp_path / "logs", from_arrays(_episodes(3), fps=50))
    assert main(["logs", "card", str(logs), f"out={tmp_path / 'card.json'}"]) == 0
    text = capsys.readouterr().out
    assert re.search(r"N_eff\s+3\.0", text) and "c = 0" in text
    doc = json.loads((tmp_path / "card.json").read_text())
    assert doc["schema"] == "bench.logs_card/1" and doc["c"] == 0 and doc["N"] == 3


@pytest.fixture(scope="module")
def arm_case(tmp_path_factory):
    """A calibrated synthetic arm (Coulomb friction on j2) and a second log: plain arm and the same arm."""
    from bench.calibrate.generate import write_case

    root = tmp_path_factory.mktemp("rank")
    case = write_case(root / "case", "coulomb_friction", episodes=3, duration=2.0, seed=0)
    return case, calibrated(case, root / "cal", "residual=false").parent


def test_rank_puts_the_episodes_the_calibration_does_not_explain_first(arm_case, tmp_path, capsys):
    from bench.calibrate.generate import simulate_arm
    from bench.calibrate.rank import rank

    case, cal = arm_case
    friction, _ = simulate_arm("coulomb_friction", episodes=2, duration=2.0, seed=5)
    damped, _ = simulate_arm("viscous_damping", episodes=2, duration=2.0, seed=6)  # j2 damping 1.2: not calibrated
    mixed = write_dataset(tmp_path / "mixed", from_arrays(friction + damped, fps=100))
    doc = rank(cal, mixed)
    assert [r["episode"] for r in doc["episodes"]][:2] in ([2, 3], [3, 2])  # the damped arm surprises most
    assert doc["episodes"][0]["surprise"] > 5 * doc["episodes"][-1]["surprise"]
    assert main(["logs", "rank", str(mixed), f"calibration={cal}", "horizon=k_step", "top=2"]) == 0
    out = capsys.readouterr().out
    rows = [ln for ln in out.splitlines() if re.match(r"\s+\d+\s+\d+", ln)]
    assert "k-step (k = 20 frames)" in out and len(rows) == 2


BAD = [
    (lambda t, c: ["card", str(t / "nowhere")], r"logs folder .*nowhere' does not exist"),
    (lambda t, c: ["card", str(c[0] / "logs"), "dup=0.1"], r"unknown key 'dup'.*Did you mean 'dup_tol'"),
    (lambda t, c: ["card", str(c[0] / "logs"), f"out={c[0] / 'spec.yaml'}"], r"out=.*spec.yaml' exists"),
    (lambda t, c: ["card", str(c[0] / "logs"), "dup_tol=-1"], r"dup_tol=-1: must be in \[0, inf\)"),
    (lambda t, c: ["rank", str(c[0] / "logs")], r"missing key 'calibration'"),
    (lambda t, c: ["rank", str(c[0] / "logs"), f"calibration={t}"], r"calibration=.*no such file"),
    (
        lambda t, c: ["rank", str(c[0] / "logs"), f"calibration={c[1]}", "horizon=long"],
        r"horizon='long'; valid: free_run, k_step",
    ),
]


@pytest.mark.parametrize(
    "make, pattern",
    BAD,
    ids=[
        "card-missing",
        "card-key",
        "card-out-exists",
        "card-tol",
        "rank-no-calibration",
        "rank-missing-file",
        "rank-horizon",
    ],
)
def test_bad_input_one_line_exit_2(arm_case, tmp_path, capsys, make, pattern):
    assert main(["logs", *make(tmp_path, arm_case)]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and re.search(pattern, err), err
