"""Statistics for experiments built on bench: intervals, trends across runs, data coverage, sim-real agreement.

The same estimators `bench run`, `bench coverage` and `bench correlate` report, for scripts that
combine runs (the coverage sweep, the Real2Sim demonstration).
"""

from __future__ import annotations

from bench.scoring.agreement import Outcome, agreement, mmrv
from bench.scoring.coverage import TrainingData, coverage_report, fmt_pct, initial_states_from_suite
from bench.scoring.stats import paired_gap, wilson
from bench.scoring.summary import fmt_estimate, load_run
from bench.scoring.trend import SeriesBootstrap, slope_with_interval

__all__ = [
    "Outcome",
    "SeriesBootstrap",
    "TrainingData",
    "agreement",
    "coverage_report",
    "fmt_estimate",
    "fmt_pct",
    "initial_states_from_suite",
    "load_run",
    "mmrv",
    "paired_gap",
    "slope_with_interval",
    "wilson",
]
