"""Bad input at the command line: one line on stderr, exit 2, nothing written."""

import subprocess
import sys

import pytest

from bench.cli import main


@pytest.mark.parametrize(
    "argv, pattern",
    [
        (["run", "episods=3"], "unknown key 'episods'.*Did you mean 'episodes'"),
        (["run", "episodes=abc"], "bad value for 'episodes'"),
        (["run", "episodes=0"], r"episodes=0: must be in \[1, "),
        (["run", "episodes=3", "episodes=5"], "key 'episodes' is given twice"),
        (["run", "env_id=HalfCheetah-v5"], "unknown key 'env_id'.*suite held_out_robots: obs, cameras, image_size"),
        (["run", "suite=gym"], "env_id: required"),
        (["run", "robots=[]"], r"robots=\[\] selects nothing"),
        (["run", "timeout=0"], r"timeout=0: must be in \(0, 604800\]"),
        (["run", "seed=-1"], r"seed=-1: must be in \[0, "),
        (["run", "horizon=-5"], r"horizon=-5: must be in \[0, "),
        (["run", "suite=held_out_robot"], "suite='held_out_robot' is not registered.*Did you mean 'held_out_robots'"),
        (["run", "policy=scriptd"], "policy='scriptd' is not registered.*Did you mean 'scripted'"),
        (["run", "robots=[Pandaa]"], "robots: 'Pandaa' is not in suite.*Did you mean 'Panda'"),
        (["run", "splits=[held]"], "splits: 'held' is not a split"),
        (["runn"], "unknown command 'runn'.*Did you mean 'run'"),
    ],
    ids=[
        "misspelled-key",
        "bad-type",
        "zero-episodes",
        "key-twice",
        "key-of-no-part",
        "missing-suite-key",
        "empty-selection",
        "zero-timeout",
        "negative-seed",
        "negative-horizon",
        "unknown-suite",
        "unknown-policy",
        "unknown-robot",
        "bad-split",
        "unknown-command",
    ],
)
def test_bad_input_exit_2_nothing_written(tmp_path, capsys, argv, pattern):
    out = tmp_path / "runs"
    code = main(argv + ([f"out={out}"] if argv[0] == "run" else []))
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    import re

    assert re.search(pattern, err), err
    assert not out.exists()


def test_console_script_help_is_fast_and_lists_commands():
    res = subprocess.run([sys.executable, "-m", "bench", "--help"], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0
    for cmd in ("run", "list", "check", "leaderboard"):
        assert f"  {cmd}" in res.stdout


def test_run_help_documents_every_key(capsys):

    from bench.execution.run_config import RUNNER_KEYS

    assert main(["run", "--help"]) == 0
    text = capsys.readouterr().out
    for name in RUNNER_KEYS:
        assert f"  {name}" in text, name
    assert main(["run", "suite=gym", "--help"]) == 0  # the suite's own keys
    assert "keys of suite gym:\n  env_id (required)" in capsys.readouterr().out
