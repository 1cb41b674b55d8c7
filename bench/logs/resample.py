"""Irregular log clocks onto a uniform grid: the one stated method importers and calibration use.

Real robots log on a jittery clock (the Franka Panda log of Gaz et al.: median period 1.000 ms,
min 0.70 ms, max 8.81 ms), while fixed-step simulation and a LeRobot dataset need one frame rate.
The method, stated wherever it is used:

    every column is linearly interpolated (`numpy.interp`) onto t_k = t_0 + k / fps, k = 0, 1, ...
    while t_k <= t_end; no extrapolation, no filtering.

Linear interpolation keeps every sample's value where the grid hits it and never overshoots
(no ringing near steps), at the price of a slight low-pass of content near the Nyquist rate of the
source clock. A gap in the source longer than `max_gap` seconds would be bridged by a straight line
that no sensor measured: it is refused with the row where it starts. `check_times` is the check of a
time column every importer makes: finite, no duplicated sample, strictly increasing.
"""

from __future__ import annotations

import numpy as np

from bench.core.errors import DataError

METHOD = "linear interpolation onto t0 + k/fps (numpy.interp), no extrapolation, no filtering"
MAX_GAP_S = 0.05  # longest source gap bridged by interpolation (50 ms: 50 frames at 1 kHz)


def _first(mask: np.ndarray) -> int:
    hit = np.flatnonzero(mask)
    return int(hit[0]) if hit.size else -1


def check_times(t: np.ndarray, where: str, column: str, offset: int = 0) -> None:
    """A time column must be finite, without duplicated samples and strictly increasing (one line otherwise)."""
    row = _first(~np.isfinite(t))
    if row >= 0:
        raise DataError(f"{where}: column {column!r} is not finite at row {row + offset}")
    dt = np.diff(t)
    row = _first(dt == 0)
    if row >= 0:
        raise DataError(
            f"{where}: column {column!r} is not increasing at row {row + 1 + offset}: it repeats the time "
            f"{t[row]:.9g} of row {row + offset} (a duplicated sample); drop duplicates before importing"
        )
    row = _first(dt < 0)
    if row >= 0:
        raise DataError(
            f"{where}: column {column!r} is not increasing at row {row + 1 + offset} "
            f"({t[row]:.9g} -> {t[row + 1]:.9g}: back in time); timestamps must increase"
        )


def is_regular(t: np.ndarray, tol: float = 0.05) -> bool:
    """True when every period is within `tol` (relative) of the median period."""
    dt = np.diff(np.asarray(t, dtype=np.float64))
    if dt.size == 0:
        return True
    med = float(np.median(dt))
    return bool(np.all(np.abs(dt - med) <= tol * med))


def resample(
    t: np.ndarray,
    columns: dict[str, np.ndarray],
    fps: float,
    *,
    where: str = "log",
    column: str = "time",
    max_gap: float = MAX_GAP_S,
) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, object]]:
    """Columns sampled at times `t` (seconds) onto a uniform grid at `fps`; and a report of what was done.

    Args:
        t: sample times in seconds, checked by `check_times`.
        columns: name -> (T,) or (T, D) arrays sampled at `t`.
        fps: the rate of the grid in Hz.
        where, column: how errors name the source and its time column.
        max_gap: the longest source period (seconds) that may be bridged; longer gaps are refused.

    Returns:
        (grid times from t[0], resampled columns as float64, report) where the report holds the
        method, the source's median / min / max period, the number of source periods longer than
        1.5 median periods and the longest one.
    """
    t = np.asarray(t, dtype=np.float64)
    check_times(t, where, column)
    if not np.isfinite(fps) or fps <= 0:
        raise DataError(f"{where}: resampling rate must be a positive number of Hz, got {fps!r}")
    if t.size < 2:
        raise DataError(f"{where}: column {column!r} has {t.size} sample(s); resampling needs at least 2")
    dt = np.diff(t)
    row = _first(dt > max_gap)
    if row >= 0:
        raise DataError(
            f"{where}: column {column!r} has a gap of {dt[row]:.4g} s after row {row} (longer than "
            f"{max_gap:g} s): interpolation would invent the missing stretch; split the log there"
        )
    n = int(np.floor((t[-1] - t[0]) * fps + 1e-9)) + 1
    grid = t[0] + np.arange(n) / fps
    out: dict[str, np.ndarray] = {}
    for name, arr in columns.items():
        a = np.asarray(arr, dtype=np.float64)
        if a.shape[0] != t.size:
            raise DataError(f"{where}: column {name!r} has {a.shape[0]} rows; the time column has {t.size}")
        flat = a.reshape(t.size, -1)
        res = np.stack([np.interp(grid, t, flat[:, j]) for j in range(flat.shape[1])], axis=1)
        out[name] = res.reshape((n, *a.shape[1:]))
    med = float(np.median(dt))
    report = {
        "method": METHOD,
        "fps": float(fps),
        "source_samples": int(t.size),
        "frames": int(n),
        "source_period_s": {"median": med, "min": float(dt.min()), "max": float(dt.max())},
        "source_periods_over_1.5x_median": int(np.sum(dt > 1.5 * med)),
    }
    return grid, out, report
