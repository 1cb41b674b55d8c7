"""`bench correlate` from Python: sim-real agreement of per-policy outcomes (`bench.scoring.agreement`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from bench.core import outputs
from bench.core.config import MAX_N_BOOT, MAX_SEED, ranged
from bench.core.errors import ConfigError, DataError
from bench.core.io import write_atomic
from bench.scoring.agreement import agreement, load_outcomes

__all__ = ["CorrelateConfig", "correlate"]


@dataclass(frozen=True)
class CorrelateConfig:
    """Keys of `bench correlate`."""

    sim: Optional[str] = (
        None  # outcome table from simulation: JSON rows {policy, trials, successes} or CSV policy,trials,successes
    )
    real: Optional[str] = None  # outcome table from the real robot, same format and the same policies
    seed: int = ranged(0, 0, MAX_SEED)  # seed of the bootstrap generator
    n_boot: int = ranged(2000, 1, MAX_N_BOOT)  # bootstrap replicates
    level: float = ranged(0.95, 0, 1, lo_open=True, hi_open=True)  # interval coverage
    out: Optional[str] = None  # also write the report as JSON (undefined values are null with a reason)
    overwrite: bool = False  # replace an existing out= file that bench wrote


def correlate(cfg: CorrelateConfig) -> dict[str, Any]:
    """The agreement report (schema bench.agreement/1) of `cfg.sim` and `cfg.real`; also written to `cfg.out`."""
    for key in ("sim", "real"):
        if not getattr(cfg, key):
            raise ConfigError(f"missing key {key!r}: bench correlate sim=FILE real=FILE")
    sim_path, real_path = str(cfg.sim), str(cfg.real)
    if cfg.out:
        outputs.check("out", cfg.out, {"sim": sim_path, "real": real_path}, kind="file", overwrite=cfg.overwrite)
    tables = {}
    for key, path in (("sim", sim_path), ("real", real_path)):
        try:
            tables[key] = load_outcomes(path)
        except DataError as exc:
            raise DataError(f"{key}={path}: {str(exc).removeprefix(str(path) + ': ')}") from None
    report = agreement(
        tables["sim"],
        tables["real"],
        n_boot=cfg.n_boot,
        seed=cfg.seed,
        level=cfg.level,
        sim_name=sim_path,
        real_name=real_path,
    )
    report = {"schema": "bench.agreement/1", "sim": sim_path, "real": real_path, **report}
    if cfg.out:
        write_atomic(Path(cfg.out), report)
    return report
