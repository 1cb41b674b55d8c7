"""Files for code built on bench: episode records, safe writes and the rule for outputs.

Experiments read the records of their runs (LeRobot datasets are `bench.api.datasets`); scripts write
their own outputs under the same rule as every bench command (`outputs.check`: an output never equals,
contains or lies inside an input; checked before the first byte is written), and name files the way
results do (`portable`: relative to the checkout when inside it).
"""

from __future__ import annotations

from bench.core import outputs
from bench.core.io import sha256_file, write_atomic, write_bytes_atomic, write_text_atomic
from bench.core.provenance import portable
from bench.records import EPISODES, EpisodeRecord, RecordWriter, comparable, dedupe, read_records

__all__ = [
    "EPISODES",
    "EpisodeRecord",
    "RecordWriter",
    "comparable",
    "dedupe",
    "outputs",
    "portable",
    "read_records",
    "sha256_file",
    "write_atomic",
    "write_bytes_atomic",
    "write_text_atomic",
]
