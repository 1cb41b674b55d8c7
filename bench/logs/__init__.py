"""Real-robot logs: LeRobot v3.0 datasets (pyarrow only) and importers from CSV, MAT and RLDS.

    from bench.logs import read_dataset, read_episode, write_dataset, from_arrays
    ds = from_arrays([{"observation.state": q, "action": u}], fps=100)
    write_dataset("logs/run1", ds)
    ep = read_episode("logs/run1", 0)          # one episode, without reading the others

See `bench.logs.dataset` for the in-memory conventions (shapes, dtypes, default columns).
"""

from __future__ import annotations

from bench.logs.dataset import Episode, LogDataset, from_arrays, validate
from bench.logs.importers import import_csv, import_mat
from bench.logs.lerobot import check_files, info, iter_episodes, read_dataset, read_episode, verify, write_dataset
from bench.logs.rlds import import_rlds

__all__ = [
    "Episode",
    "LogDataset",
    "from_arrays",
    "validate",
    "read_dataset",
    "read_episode",
    "iter_episodes",
    "write_dataset",
    "info",
    "check_files",
    "verify",
    "import_csv",
    "import_mat",
    "import_rlds",
]
