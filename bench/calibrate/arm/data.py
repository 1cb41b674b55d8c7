"""A real arm's logs as inverse dynamics needs them: uniform clock, filtered, differentiated, split.

The stated processing, per episode:
1. the log's own clock (`time_ns`, else `timestamp`): if its periods are not uniform (within 5% of
   the median), every column is resampled onto a uniform grid at the median rate by linear
   interpolation (`bench.logs.resample`, which also refuses gaps longer than 50 ms);
2. positions, velocities and torques are low-passed by a 4th-order zero-phase Butterworth filter at
   `filter_hz` (the same filter on every signal, so their delays cancel: "parallel filtering");
3. velocities not logged are the filtered positions' central difference; accelerations are always
   the filtered velocities' central difference;
4. everything is decimated to `rate` Hz (the filter is the anti-aliasing filter) and `margin`
   samples at each end (filter edge effects) are dropped.

Held out (`bench.calibrate.novelty`): by default the `holdout` share that repeats the rest least (a
window of time in a one-episode log, else whole episodes), with a guard band of `GUARD_PERIODS` filter
periods on either side that no fitted sample uses (the zero-phase filter spans the split); `holdout_at:
end` holds out the last share of time (or a seeded share of episodes), `holdout: [t0, t1]` a window.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from bench.calibrate import novelty
from bench.calibrate.arm.spec import ArmSpec
from bench.core.errors import DataError, SpecError
from bench.logs.resample import is_regular, resample
from bench.replay.data import Window, column

EDGE_S = 0.1  # seconds dropped at each end of an episode after filtering
GUARD_PERIODS = 4.0  # guard band around held-out data, in periods of the filter's cut-off (0.2 s at 20 Hz)


@dataclass
class ArmLog:
    """Processed samples of all episodes, concatenated, at the identification rate."""

    t: np.ndarray  # (N,) seconds from each episode's start
    episode: np.ndarray  # (N,) episode number
    q: np.ndarray  # (N, n)
    dq: np.ndarray
    ddq: np.ndarray
    tau: np.ndarray  # (N, n) the torque signal (measured torque, command or current)
    train: np.ndarray  # (N,) bool: fitted rows
    hold: np.ndarray  # (N,) bool: held-out rows (neither: the guard bands between them)
    rate: float
    source_fps: float  # the log's (uniform or resampled) rate before decimation
    qvel_logged: bool
    resampled: list[dict[str, Any]]  # per episode: what resampling did (empty when the clock was uniform)
    dense: dict[str, np.ndarray]  # filtered q, dq, tau at the source rate, episodes concatenated
    dense_offsets: np.ndarray  # (E + 1,) episode offsets of `dense`
    dense_train: list[tuple[int, int, int]]  # (episode, start, stop) training windows of `dense`
    dense_hold: list[tuple[int, int, int]]
    heldout: novelty.Heldout  # where the held-out data are and how much of them repeats the fitted


def _clock(ep: dict[str, np.ndarray], fps: float) -> np.ndarray:
    if "time_ns" in ep:
        ns = np.asarray(ep["time_ns"]).reshape(-1).astype(np.int64)
        return (ns - ns[0]).astype(np.float64) * 1e-9
    if "timestamp" in ep:
        return np.asarray(ep["timestamp"], dtype=np.float64).reshape(-1)
    return np.arange(len(next(iter(ep.values())))) / fps


def _filter(x: np.ndarray, fs: float, cutoff: float) -> np.ndarray:
    from scipy.signal import butter, sosfiltfilt  # scipy: loaded only when a log is processed

    sos = butter(4, cutoff, fs=fs, output="sos")
    return sosfiltfilt(sos, x, axis=0)


def load_arm_log(spec: ArmSpec, episodes: list[dict[str, np.ndarray]], fps: float, seed: int) -> ArmLog:
    """Process the episodes as the module docstring states; one line naming the column on bad data."""
    if not episodes:
        raise DataError("the log holds no episode")
    parts: dict[str, list[np.ndarray]] = {k: [] for k in ("t", "ep", "q", "dq", "ddq", "tau")}
    dense: dict[str, list[np.ndarray]] = {"q": [], "dq": [], "tau": []}
    resampled, lengths, source_rates = [], [], []
    for i, ep in enumerate(episodes):
        cols = {k: column(ep, s, f"signals.{k}", i) for k, s in spec.signals.items()}
        t = _clock(ep, fps)
        if not is_regular(t):
            rate = float(1.0 / np.median(np.diff(t)))
            rate = float(round(rate)) if abs(rate - round(rate)) <= 1e-3 * rate else rate
            t, cols, report = resample(t, cols, rate, where=f"episode {i}", column="time_ns")
            resampled.append({"episode": i, **report})
            src = rate
        else:
            src = float(1.0 / np.median(np.diff(t))) if len(t) > 1 else fps
        source_rates.append(src)
        margin = int(round(EDGE_S * src))
        step = max(1, int(round(src / spec.rate)))
        if len(t) < 2 * margin + 10 * step:
            raise DataError(
                f"episode {i} has {len(t)} samples at {src:g} Hz: too short to filter and decimate to {spec.rate:g} Hz"
            )
        if spec.filter_hz >= src / 2:
            raise SpecError(
                f"spec field 'filter_hz' ({spec.filter_hz:g}) must be below half the log's rate ({src:g} Hz)"
            )
        q = _filter(cols["qpos"], src, spec.filter_hz)
        dq = _filter(cols["qvel"], src, spec.filter_hz) if "qvel" in cols else np.gradient(q, 1.0 / src, axis=0)
        tau = _filter(cols["torque"], src, spec.filter_hz)
        ddq = np.gradient(dq, 1.0 / src, axis=0)
        keep = np.arange(margin, len(t) - margin, step)
        parts["t"].append(t[keep] - t[0])  # the episode's own clock
        parts["ep"].append(np.full(len(keep), i))
        for k, v in (("q", q), ("dq", dq), ("ddq", ddq), ("tau", tau)):
            parts[k].append(v[keep])
        for k, v in (("q", q), ("dq", dq), ("tau", tau)):
            dense[k].append(v[margin : len(t) - margin])
        lengths.append(len(keep))
    if len(set(round(r, 6) for r in source_rates)) != 1:
        raise DataError(f"episodes are logged at different rates ({sorted(set(source_rates))} Hz); import them apart")
    t_all, ep_all = np.concatenate(parts["t"]), np.concatenate(parts["ep"])
    rate = float(source_rates[0] / max(1, int(round(source_rates[0] / spec.rate))))
    states = [np.hstack([q, dq]) for q, dq in zip(parts["q"], parts["dq"])]
    train_w, hold_w, heldout = choose_split(spec, states, parts["t"], rate, seed)
    train = np.zeros(len(t_all), bool)
    offsets = np.concatenate([[0], np.cumsum(lengths)])
    hold = np.zeros(len(t_all), bool)
    for ws, mask in ((train_w, train), (hold_w, hold)):
        for w in ws:
            mask[offsets[w.episode] + w.start : offsets[w.episode] + w.stop] = True
    dense_len = [len(x) for x in dense["q"]]
    dense_off = np.concatenate([[0], np.cumsum(dense_len)])

    def dense_windows(ws: list) -> list[tuple[int, int, int]]:
        out = []
        for w in ws:
            n = dense_len[w.episode]
            scale = n / lengths[w.episode]
            out.append((w.episode, int(round(w.start * scale)), min(n, int(round(w.stop * scale)))))
        return out

    return ArmLog(
        t=t_all,
        episode=ep_all,
        q=np.concatenate(parts["q"]),
        dq=np.concatenate(parts["dq"]),
        ddq=np.concatenate(parts["ddq"]),
        tau=np.concatenate(parts["tau"]),
        train=train,
        hold=hold,
        rate=rate,
        source_fps=float(source_rates[0]),
        qvel_logged="qvel" in spec.signals,
        resampled=resampled,
        dense={k: np.concatenate(v) for k, v in dense.items()},
        dense_offsets=dense_off,
        dense_train=dense_windows(train_w),
        dense_hold=dense_windows(hold_w),
        heldout=heldout,
    )


def choose_split(
    spec: ArmSpec, states: list[np.ndarray], clocks: list[np.ndarray], rate: float, seed: int
) -> tuple[list[Window], list[Window], novelty.Heldout]:
    """Fitted and held-out windows (rows at the identification rate) and how new the held-out ones are
    (`bench.calibrate.novelty.choose`, with a guard band of GUARD_PERIODS filter periods and at least 10
    fitted rows)."""
    return novelty.choose(
        states,
        clocks,
        share=spec.holdout,
        window=spec.holdout_window,
        at=spec.holdout_at,
        guard=int(round(GUARD_PERIODS / spec.filter_hz * rate)),
        seed=seed,
        period=spec.period,
        min_fit=10,
    )
