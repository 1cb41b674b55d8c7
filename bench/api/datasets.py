"""LeRobot v3 datasets, read and written with pyarrow alone: what `bench run record=` writes, what baselines train on.

Kept apart from `bench.api.data` because it imports pyarrow, which a policy plugin or a suite should not pay
for at start-up.
"""

from __future__ import annotations

from bench.logs import import_csv, read_dataset, write_dataset

__all__ = ["import_csv", "read_dataset", "write_dataset"]
