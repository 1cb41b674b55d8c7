"""The calibration's view of the logs: the spec's signals with its held-out split.

The recording itself (columns, widths, velocity estimate, split) is replay's
(`bench.replay.data`); calibration adds only which share of it is held out.
"""

from __future__ import annotations

import numpy as np

from bench.calibrate.spec import CalibrationSpec
from bench.replay.data import Recording
from bench.replay.data import extract as extract_signals


def extract(
    spec: CalibrationSpec,
    episodes: list[dict[str, np.ndarray]],
    fps: float,
    *,
    nq: int,
    nv: int,
    nu: int,
    seed: int = 0,
) -> Recording:
    """Pick the spec's signals out of the episodes, check their widths, hold out `spec.holdout` (seeded)."""
    return extract_signals(spec, episodes, fps, nq=nq, nv=nv, nu=nu, holdout=spec.holdout, seed=seed)
