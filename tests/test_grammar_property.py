"""Property tests over the key=value grammar (issue 14, deliverable 4).

Random keys and values (unicode, control characters, brackets, quotes, numbers at the
extremes, NaN/inf, duplicates, empty values) are fed to the typed parsers of every
command. Each input must either parse or raise a `BenchError` whose message is one line;
any other exception is a bug. A sample also goes through `bench.cli.main` in an empty
temporary folder, which must stay empty when the command is refused.
"""

from __future__ import annotations

import dataclasses
import math
import os

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bench import api
from bench.core import config as config_mod
from bench.core.errors import BenchError
from bench.execution import run_config

SETTINGS = dict(
    deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture]
)


def _schemas() -> list[type]:
    from bench.api.calibration import CalibrateConfig, DesignConfig, GenerateConfig, SuiteCalibrateConfig
    from bench.cli.check import CheckConfig
    from bench.cli.correlate import CorrelateConfig
    from bench.cli.coverage import CoverageConfig
    from bench.cli.leaderboard import MergeConfig
    from bench.cli.logs import FORMATS, CardConfig, ImportConfig, RankConfig
    from bench.cli.perf import PerfConfig
    from bench.cli.regress_args import RegressConfig
    from bench.cli.report import ReportConfig
    from bench.replay.common import ReplayConfig

    return [
        api.RunConfig,
        CorrelateConfig,
        CheckConfig,
        CoverageConfig,
        PerfConfig,
        RegressConfig,
        ReplayConfig,
        ReportConfig,
        ImportConfig,
        *FORMATS.values(),
        CardConfig,
        RankConfig,
        CalibrateConfig,
        SuiteCalibrateConfig,
        GenerateConfig,
        DesignConfig,
        MergeConfig,
    ]


SCHEMAS = _schemas()
RUN_KEYS = [f.name for f in dataclasses.fields(api.RunConfig)]
ALL_KEYS = sorted({f.name for s in SCHEMAS for f in dataclasses.fields(s)})

numbers = st.one_of(
    st.integers(min_value=-(2**70), max_value=2**70).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(
        [
            "nan",
            "NaN",
            "inf",
            "-inf",
            ".inf",
            "-.inf",
            "1e300",
            "-1e300",
            "1e-320",
            "0",
            "-0",
            "0x10",
            "1_000",
            "007",
            "2**63",
            "9" * 40,
        ]
    ),
)
weird = st.text(st.characters(codec="utf-8", exclude_categories=("Cs",)), max_size=12)
punct = st.sampled_from(
    [
        "[",
        "]",
        "[]",
        "{}",
        "{",
        "}",
        "'",
        '"',
        "''",
        ",",
        ":",
        "=",
        "${x}",
        "${",
        "\\",
        "/",
        "..",
        "\x00",
        "\x1b[31m",
        "\n",
        " ",
        "[Panda",
        "[a,[b]]",
        "[1,2",
        "a,b",
        "~",
        "null",
        "true",
        "yes",
        "%",
        "!!python/object",
        "&a",
        "*a",
        "#",
    ]
)
values = st.one_of(
    numbers,
    weird,
    punct,
    st.lists(st.one_of(numbers, weird, punct), max_size=3).map(lambda xs: "[" + ",".join(xs) + "]"),
)
keys = st.one_of(
    st.sampled_from(ALL_KEYS),
    st.sampled_from(ALL_KEYS).map(lambda k: k + ".x"),
    weird,
    st.sampled_from(
        ["", ".", "a..b", "perturb.friction", "perturb.latency", "perturb.", "robots[0]", "__class__", "suite.x"]
    ),
)
overrides = st.lists(st.tuples(keys, values).map(lambda kv: f"{kv[0]}={kv[1]}"), min_size=0, max_size=4)


def _one_line(exc: BenchError) -> None:
    msg = str(exc)
    assert msg and "\n" not in msg and "\r" not in msg, repr(msg)
    assert "Traceback" not in msg


def _build(schema: type, argv: list[str]) -> object | None:
    try:
        obj = config_mod.build(schema, argv)
    except BenchError as exc:
        _one_line(exc)
        return None
    # what parsed holds no NaN/inf anywhere
    assert _non_finite(dataclasses.asdict(obj), "") is None  # type: ignore[arg-type]
    return obj


def _non_finite(value: object, path: str) -> str | None:
    """The path of the first NaN/inf float or integer beyond 64 bits inside `value`, or None."""
    if isinstance(value, float):
        return None if math.isfinite(value) else path
    if isinstance(value, int) and not isinstance(value, bool) and not -(2**63) <= value < 2**63:
        return path
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, (list, tuple)) else ()
    for k, v in items:
        found = _non_finite(v, f"{path}.{k}")
        if found:
            return found
    return None


@settings(max_examples=600, **SETTINGS)
@given(st.sampled_from(SCHEMAS), overrides)
def test_build_parses_or_refuses_in_one_line(schema: type, argv: list[str]) -> None:
    """Every command's typed config: parse or one-line BenchError, nothing else."""
    _build(schema, argv)


@settings(max_examples=400, **SETTINGS)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(RUN_KEYS + ["perturb.friction", "perturb.latency", "checkpoint", "robots", "nonsense"]),
            values,
        ).map(lambda kv: f"{kv[0]}={kv[1]}"),
        max_size=4,
    )
)
def test_run_config_parses_or_refuses_in_one_line(argv: list[str]) -> None:
    """`bench run` arguments routed to runner, suite and policy, then the runner's ranges."""
    try:
        cfg = api.config_from_argv(["suite=held_out_robots", *argv])
        run_config.check_runner(cfg)
    except BenchError as exc:
        _one_line(exc)
        return
    for f in ("timeout", "actor_cpus", "actor_gpus", "confidence"):
        assert math.isfinite(getattr(cfg, f)), f
    assert 0 <= cfg.horizon <= run_config.MAX_HORIZON and 0 <= cfg.workers <= run_config.MAX_WORKERS
    assert cfg.n_boot <= run_config.MAX_N_BOOT and cfg.seed >= 0


@settings(max_examples=200, **SETTINGS)
@given(st.sampled_from(RUN_KEYS), st.lists(values, min_size=2, max_size=3))
def test_a_key_given_twice_is_refused(key: str, vals: list[str]) -> None:
    """Duplicates never silently take the last value."""
    with pytest.raises(BenchError) as info:
        config_mod.build(api.RunConfig, [f"{key}={v}" for v in vals])
    _one_line(info.value)


@settings(max_examples=150, **SETTINGS)
@given(
    st.sampled_from(["score", "correlate", "replay", "report", "regress", "coverage", "perf"]),
    st.lists(
        st.tuples(
            st.sampled_from(
                ["n_boot", "confidence", "level", "seed", "k", "workers", "horizon", "timeout", "episodes", "nonsense"]
            ),
            values,
        ).map(lambda kv: f"{kv[0]}={kv[1]}"),
        min_size=1,
        max_size=3,
    ),
)
def test_cli_refuses_in_one_line_and_writes_nothing(tmp_path_factory, capsys, command: str, argv: list[str]) -> None:
    """`bench <command>` with hostile numeric keys: exit 0/2 with one stderr line; an empty cwd stays empty
    when refused. The run directory argument points at a folder that does not exist, so nothing runs."""
    from bench import cli

    capsys.readouterr()
    cwd = tmp_path_factory.mktemp("cli")
    old = os.getcwd()
    os.chdir(cwd)
    try:
        pos = [] if command in ("perf", "coverage", "correlate", "regress") else ["no-such-run"]
        code = cli.main([command, *pos, *argv])
    finally:
        os.chdir(old)
    err = capsys.readouterr().err
    assert code in (0, 2), (code, err)
    if code == 2:
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err, err
        assert not any(cwd.iterdir()), list(cwd.iterdir())


def test_absurd_work_is_refused_up_front_naming_the_keys(tmp_path) -> None:
    """Every key in range, the product not: refused by plan() before anything is written."""
    cfg = api.config_from_argv(
        ["suite=tests.toy_suite:ToySuite", "episodes=100000", "horizon=100000", f"out={tmp_path}/runs"]
    )
    with pytest.raises(BenchError, match=r"control steps, over the limit of 1e\+10; reduce episodes=, horizon="):
        api.plan(cfg)
    assert not any(tmp_path.iterdir())


def test_latency_longer_than_the_episode_is_refused() -> None:
    cfg = api.config_from_argv(["suite=tests.toy_suite:ToySuite", "episodes=1", "perturb.latency=[100000000]"])
    with pytest.raises(BenchError, match=r"perturb.latency.*(horizon|<= 100000)"):
        api.plan(cfg)
