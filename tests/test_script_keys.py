"""Benchmark scripts' `key=value` arguments (bench.api.scripts.script_keys): --help prints the docstring, a key the
script does not read is one line and exit 2 (before any work), a bare word too."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from bench.api.scripts import script_keys, whole
from bench.core.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]


def test_keys_are_returned_as_strings():
    assert script_keys(["servo=sts3250", "folds=true"], "doc", ("servo", "folds")) == {
        "servo": "sts3250",
        "folds": "true",
    }


@pytest.mark.parametrize("arg", ["servoo=x", "xl330", "=1"])
def test_a_key_the_script_does_not_read_is_one_line_and_exit_2(arg, capsys):
    with pytest.raises(SystemExit) as e:
        script_keys([arg], "doc", ("servo", "folds"))
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "folds, servo" in err[0]


def test_a_whole_number_key_is_read_or_named_in_its_error():
    keys = {"steps": "20", "solvers": "abc"}
    assert whole(keys, "steps", 10) == 20 and whole(keys, "episodes", 64) == 64
    with pytest.raises(ConfigError, match=r"^solvers='abc': expected a whole number$"):
        whole(keys, "solvers", 0)


def test_help_prints_the_docstring(capsys):
    with pytest.raises(SystemExit) as e:
        script_keys(["--help"], "  What it does.\n", ("servo",))
    assert e.value.code == 0 and capsys.readouterr().out == "What it does.\n"


def test_a_benchmark_refuses_a_misspelt_key_before_working():
    r = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "bench_servo.py"), "servoo=sts3250"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2 and "Did you mean 'servo'?" in r.stderr and r.stdout == ""
