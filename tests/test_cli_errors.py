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
        (["run", "episodes=0"], "episodes=0: must be >= 1"),
        (["run", "suite=held_out_robot"], "suite='held_out_robot' is not registered.*Did you mean 'held_out_robots'"),
        (["run", "policy=scriptd"], "policy='scriptd' is not registered.*Did you mean 'scripted'"),
        (["run", "robots=[Pandaa]"], "robots: 'Pandaa' is not in suite.*Did you mean 'Panda'"),
        (["run", "splits=[held]"], "splits: 'held' is not a split"),
        (["runn"], "unknown command 'runn'.*Did you mean 'run'"),
    ],
    ids=["misspelled-key", "bad-type", "zero-episodes", "unknown-suite", "unknown-policy", "unknown-robot",
         "bad-split", "unknown-command"],
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
    import dataclasses

    from bench.run import RunConfig

    assert main(["run", "--help"]) == 0
    text = capsys.readouterr().out
    for f in dataclasses.fields(RunConfig):
        assert f"  {f.name}" in text, f.name
