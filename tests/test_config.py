"""Config: Hydra-style overrides onto typed frozen configs; errors are one line with a suggestion."""

import dataclasses
from typing import Optional

import pytest

from bench.api import RunConfig
from bench.cli import main
from bench.core.config import build, one_or_more, split_args
from bench.core.errors import ConfigError


def test_overrides_nested_and_lists():
    cfg = build(RunConfig, ["episodes=3", "robots=[UR5e,IIWA]", "perturb.friction=[0.5,1.0]", "seed=7"])
    assert cfg.episodes == 3 and cfg.seed == 7
    assert cfg.robots == ["UR5e", "IIWA"]
    assert cfg.perturb == {"friction": [0.5, 1.0]}


def test_config_is_frozen():
    cfg = build(RunConfig, [])
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.episodes = 5  # type: ignore[misc]


def test_unknown_key_suggests_closest():
    with pytest.raises(ConfigError, match=r"unknown key 'episods'.*Did you mean 'episodes'\?"):
        build(RunConfig, ["episods=3"])


def test_wrong_type_names_key():
    with pytest.raises(ConfigError, match=r"bad value for 'episodes'"):
        build(RunConfig, ["episodes=many"])


def test_not_key_value():
    with pytest.raises(ConfigError, match="is not key=value"):
        build(RunConfig, ["=3"])


def test_split_args_keeps_positionals_apart():
    assert split_args(["info", "DIR", "out=x", "a.b=[1,2]", "b"]) == (["info", "DIR", "b"], ["out=x", "a.b=[1,2]"])


@dataclasses.dataclass(frozen=True)
class _Names:
    state: Optional[list[str]] = one_or_more()  # columns
    robots: Optional[list[str]] = None  # a plain list key


def test_one_or_more_takes_a_bare_name_plain_lists_do_not():
    assert build(_Names, ["state=q"]).state == ["q"]
    assert build(_Names, ["state=[q,v]"]).state == ["q", "v"]
    assert build(_Names, ['state="a,b"']).state == ["a,b"]
    with pytest.raises(ConfigError, match=r"bad value in state=\{a: 1\}"):
        build(_Names, ["state={a: 1}"])
    with pytest.raises(ConfigError, match=r"bad value for 'robots'"):
        build(_Names, ["robots=Panda"])
    with pytest.raises(ConfigError, match=r"state=\[\] selects nothing"):
        build(_Names, ["state=[]"])


# The commands that parsed their keys by hand (logs, calibrate, leaderboard merge) now go through `build`:
# an unknown key lists the valid ones, a bad value names its key, and both exit 2 with one line.
@pytest.mark.parametrize(
    "argv, pattern",
    [
        (
            ["logs", "card", "DIR", "dup=0.1"],
            r"unknown key 'dup'; valid keys: suite, episodes, seed, dup_tol, overlap_tol, out\. Did you mean 'dup_tol'\?",
        ),
        (["logs", "card", "DIR", "episodes=many"], r"bad value for 'episodes'"),
        (["logs", "card", "DIR", "episodes=20000"], r"episodes=20000: must be in \[0, 10000\]"),
        (["logs", "rank", "DIR", "calibration=c.json", "top=-1"], r"top=-1: must be in \[0, inf\)"),
        (["logs", "rank", "DIR", "tops=3"], r"unknown key 'tops'; valid keys: calibration, horizon, top, out\."),
        (["logs", "import", "x.csv", "out=o", "fps=0"], r"fps=0: must be in \(0, 10000\]"),
        (["logs", "import", "x.csv", "out=o", "task=[a,b]"], r"bad value for 'task'"),
        (
            ["logs", "import", "x.mat", "out=o", "split=train"],
            r"unknown key 'split' \(for format=mat\); valid keys — all formats: out, format, fps, task, robot_type, overwrite; mat: state, action, time, velocity\.",
        ),
        (["logs", "import", "x.mat", "out=o", "velocity=sometimes"], r"bad value for 'velocity'"),
        (["calibrate", "spec=s.yaml", "logs=l", "out=o", "threads=0"], r"threads=0: must be in \[1, 256\]"),
        (
            ["calibrate", "spec=s.yaml", "logs=l", "out=o", "robot=x"],
            r"unknown key 'robot'; valid keys: spec, logs, out, seed, effects, threads",
        ),
        (
            ["calibrate", "suite=s", "robot=r", "logs=l", "out=o", "effects=all"],
            r"unknown key 'effects'; valid keys: suite, robot, logs, out, condition",
        ),
        (["calibrate", "spec=s.yaml", "logs=l"], r"missing key 'out'"),
        (
            ["calibrate", "generate", "effect=none", "out=o", "duration=inf"],
            r"duration=inf: not a finite number; valid: \(0, 3600\]",
        ),
        (["calibrate", "generate", "effect=none", "out=o", "episodes=1"], r"episodes=1: must be in \[2, 10000\]"),
        (["leaderboard", "merge", "run", "out=x.json", "overwrite=maybe"], r"bad value for 'overwrite'"),
        (
            ["leaderboard", "merge", "run", "out=x.json", "outt=y"],
            r"unknown key 'outt'; valid keys: out, overwrite, allow_spec_change\.",
        ),
    ],
)
def test_typed_keys_of_logs_calibrate_leaderboard(argv, pattern, capsys, tmp_path, monkeypatch):
    import re

    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and re.search(pattern, err), err
    assert list(tmp_path.iterdir()) == []  # refused before anything was written
