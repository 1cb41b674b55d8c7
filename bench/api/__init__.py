"""The typed Python API: one function per `bench` command, and the run itself (docs/api.md).

    from bench import api

    result = api.run(api.RunConfig(suite="held_out_robots", policy="scripted", robots=["Panda"], episodes=2))
    print(result.summary["splits"]["seen"]["success_once"]["mean"])

`plan` checks everything a run needs (the key checks are `bench.execution.run_config`'s) and writes
nothing (`bench.api.planning`); `run` executes a plan (or a config) into OUT/RUN_ID (episodes.jsonl,
run.json, summary.json), resuming recorded episodes (`bench.api.running`). Every other command has its function here too, in a
module by topic (`bench.api.checks`, `bench.api.board`, `bench.api.logs`, ...), re-exported below
and imported only when first used, so `import bench.api` loads no simulator, pyarrow or plotting.
The CLI (`bench.cli`) only parses `key=value` arguments, calls these functions and prints.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

from bench.api.planning import (
    Calibration,
    ParsedRun,
    Plan,
    config_from_argv,
    load_policy,
    load_suite,
    make_executor,
    parse_run,
    plan,
    plan_with_workers,
    workers_for,
)
from bench.api.running import RunResult, calibration_notes, context, finish, run, score, start, worker
from bench.core.errors import (
    BenchError,
    ConfigError,
    DataError,
    NothingMeasured,
    RegistryError,
    SpecError,
    SplitError,
    did_you_mean,
    valid_choices,
)
from bench.execution.rollout import RunContext
from bench.execution.run_config import RUNNER_KEYS, RunConfig
from bench.execution.run_lock import RunLocked
from bench.scoring.summary import nothing_measured
from bench.scoring.summary import render as render_summary

if TYPE_CHECKING:  # the command functions, imported on first use (`__getattr__` below)
    from bench.api.agreement import CorrelateConfig, correlate
    from bench.api.board import (
        MergeConfig,
        ReportConfig,
        leaderboard_merge,
        leaderboard_show,
        leaderboard_validate,
        report,
    )
    from bench.api.calibration import (
        CalibrateConfig,
        DesignConfig,
        GenerateConfig,
        SuiteCalibrateConfig,
        calibrate,
        calibrate_robot,
        design_excitation,
        effects,
        generate_case,
    )
    from bench.api.checks import CheckConfig, check
    from bench.api.compare import CompareConfig, compare
    from bench.api.data_coverage import CoverageConfig, coverage
    from bench.api.gate import RegressConfig, regress, regress_budget
    from bench.api.logs import (
        CardConfig,
        ImportConfig,
        RankConfig,
        import_log,
        log_card,
        log_info,
        rank_log,
        verify_log,
    )
    from bench.api.plugins import list_plugins, plugin_keys
    from bench.api.policy_on_logs import ActionsConfig, actions
    from bench.api.predict import PredictConfig, predict_real
    from bench.api.replays import ReplayConfig, replay
    from bench.api.serving import ServeConfig, serve
    from bench.api.sweep import SweepConfig, sweep
    from bench.api.throughput import PerfConfig, perf

# the public face (docs/api.md): the config and its checks live in bench.execution.run_config
__all__ = [
    "BenchError",
    "ConfigError",
    "DataError",
    "NothingMeasured",
    "RegistryError",
    "RunLocked",
    "SpecError",
    "SplitError",
    "did_you_mean",
    "valid_choices",
    "Calibration",
    "ParsedRun",
    "Plan",
    "RUNNER_KEYS",
    "RunConfig",
    "RunContext",
    "RunResult",
    "calibration_notes",
    "config_from_argv",
    "context",
    "finish",
    "load_policy",
    "load_suite",
    "make_executor",
    "nothing_measured",
    "parse_run",
    "plan",
    "plan_with_workers",
    "render_summary",
    "run",
    "score",
    "start",
    "worker",
    "workers_for",
    # the other commands (one function each), from the modules named in `_LAZY`
    "ActionsConfig",
    "CalibrateConfig",
    "CardConfig",
    "CheckConfig",
    "CompareConfig",
    "CorrelateConfig",
    "CoverageConfig",
    "DesignConfig",
    "GenerateConfig",
    "ImportConfig",
    "MergeConfig",
    "PerfConfig",
    "PredictConfig",
    "RankConfig",
    "RegressConfig",
    "ReplayConfig",
    "ReportConfig",
    "ServeConfig",
    "SweepConfig",
    "SuiteCalibrateConfig",
    "actions",
    "calibrate",
    "calibrate_robot",
    "check",
    "compare",
    "correlate",
    "coverage",
    "design_excitation",
    "effects",
    "generate_case",
    "import_log",
    "leaderboard_merge",
    "leaderboard_show",
    "leaderboard_validate",
    "list_plugins",
    "log_card",
    "log_info",
    "perf",
    "predict_real",
    "plugin_keys",
    "rank_log",
    "regress",
    "regress_budget",
    "replay",
    "report",
    "serve",
    "sweep",
    "verify_log",
]

# name -> the module of bench.api that defines it; imported when the name is first used, so that `import
# bench.api` (every plugin and command pays it) loads no simulator, pyarrow or matplotlib
_LAZY: dict[str, str] = {
    **dict.fromkeys(["ActionsConfig", "actions"], "policy_on_logs"),
    **dict.fromkeys(["CorrelateConfig", "correlate"], "agreement"),
    **dict.fromkeys(
        ["MergeConfig", "ReportConfig", "leaderboard_merge", "leaderboard_show", "leaderboard_validate", "report"],
        "board",
    ),
    **dict.fromkeys(
        [
            "CalibrateConfig",
            "DesignConfig",
            "GenerateConfig",
            "SuiteCalibrateConfig",
            "calibrate",
            "calibrate_robot",
            "design_excitation",
            "effects",
            "generate_case",
        ],
        "calibration",
    ),
    **dict.fromkeys(["CheckConfig", "check"], "checks"),
    **dict.fromkeys(["CompareConfig", "compare"], "compare"),
    **dict.fromkeys(["CoverageConfig", "coverage"], "data_coverage"),
    **dict.fromkeys(
        ["CardConfig", "ImportConfig", "RankConfig", "import_log", "log_card", "log_info", "rank_log", "verify_log"],
        "logs",
    ),
    **dict.fromkeys(["PerfConfig", "perf"], "throughput"),
    **dict.fromkeys(["list_plugins", "plugin_keys"], "plugins"),
    **dict.fromkeys(["RegressConfig", "regress", "regress_budget"], "gate"),
    **dict.fromkeys(["ReplayConfig", "replay"], "replays"),
    **dict.fromkeys(["ServeConfig", "serve"], "serving"),
    **dict.fromkeys(["PredictConfig", "predict_real"], "predict"),
    **dict.fromkeys(["SweepConfig", "sweep"], "sweep"),
}


def __getattr__(name: str) -> object:
    """A command's function or config, from its module (imported now: the first use of one of its names)."""
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'bench.api' has no attribute {name!r}")
    value = getattr(importlib.import_module(f"bench.api.{module}"), name)
    globals()[name] = value  # the next use is a plain lookup
    return value
