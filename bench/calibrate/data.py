"""The calibration's view of the logs: the spec's signals with its held-out split.

The recording itself (columns, widths, velocity estimate) is replay's (`bench.replay.data`);
calibration adds which part of it is held out and how new that part is (`bench.calibrate.novelty`):
by default the `holdout` share that repeats the fitted data least (the least repeated stretch of a
one-episode log, the least repeated episodes of several), else the last share of time or a seeded
share of episodes (`holdout_at: end`, as before), or a window the spec names (`holdout: [t0, t1]`).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import numpy as np

from bench.calibrate import novelty
from bench.calibrate.spec import CalibrationSpec
from bench.core.errors import DataError, SpecError
from bench.replay.data import Recording, Window, split
from bench.replay.data import extract as extract_signals


@dataclass
class SplitRecording(Recording):
    """A recording with its held-out split described (where it sits, how much of it repeats the fitted data)."""

    heldout: novelty.Heldout | None = None


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
    """Pick the spec's signals out of the episodes, check their widths, hold out what the spec asks (`choose_split`)."""
    rec = extract_signals(spec, episodes, fps, nq=nq, nv=nv, nu=nu, holdout=None, seed=seed)
    return with_split(rec, spec, seed)


def with_split(rec: Recording, spec: CalibrationSpec, seed: int = 0) -> SplitRecording:
    """The recording with the spec's held-out split (`choose_split`) in place of its own."""
    states = [states_of(rec, w) for w in rec.episodes()]
    train, hold, heldout = choose_split(spec, states, rec.fps, seed)
    base = {f.name: getattr(rec, f.name) for f in fields(Recording)}
    return SplitRecording(**{**base, "train": train, "holdout": hold}, heldout=heldout)


def states_of(rec: Recording, w: Window) -> np.ndarray:
    """[qpos, qvel] of one window's frames: the states whose repeats are measured."""
    rows = rec.frames([w])
    return np.concatenate([rec.qpos[rows], rec.qvel[rows]], axis=1)


def choose_split(
    spec: CalibrationSpec, states: list[np.ndarray], fps: float, seed: int
) -> tuple[list[Window], list[Window], novelty.Heldout]:
    """Fitted and held-out windows of episodes with these states ([qpos, qvel] per frame) and how new the
    held-out ones are.

    Several episodes: the least repeated ones, in bands of 0.1 above the least repeated share
    (`novelty.least_repeated_episodes`), so a log whose episodes are all new keeps the seeded split.

    The guard band is 0 frames: the forward path fits no filtered signal (a velocity estimated from
    positions is a ~20 ms derivative that only starts simulated horizons; nothing fitted smooths across
    the split), so the frames right before and after a held-out window are fitted. One episode: the
    fitted windows are the frames before and after the held-out one (two windows of one episode; each
    gets its own horizons, `bench.replay.simulate.horizons`). Bad choices are one line naming the spec
    field: a window that leaves no fitted data, a window in a log of several episodes, an episode
    shorter than one declared period.
    """
    lengths = [len(x) for x in states]
    scale = novelty.spread(np.concatenate(states))
    if spec.period is not None:
        short = [i for i, n in enumerate(lengths) if (n - 1) / fps < spec.period]
        if short:
            i = short[0]
            raise DataError(
                f"episode {i} holds {(lengths[i] - 1) / fps:.3g} s, less than one period of its excitation "
                f"(spec field 'period': {spec.period:g} s): a log must hold at least one whole period"
            )
        period: float | None = spec.period
        r: float | None = None
        source = "declared"
    else:
        period, r = novelty.period_of(states[int(np.argmax(lengths))], fps)
        source = "detected"
    end_share = None
    if len(states) == 1:
        train, hold, placement, end_share = _one_episode(spec, states[0], fps, scale)
    else:
        if spec.holdout_window:
            raise SpecError(
                "spec field 'holdout': a time window needs a one-episode log; this one has "
                f"{len(states)} episodes (give a share instead)"
            )
        if spec.holdout_at == "least_repeated":
            n_hold = min(len(states) - 1, max(1, int(round(spec.holdout * len(states)))))
            held = set(novelty.least_repeated_episodes(states, n_hold, seed))
            train = [Window(i, 0, n) for i, n in enumerate(lengths) if i not in held]
            hold = [Window(i, 0, n) for i, n in enumerate(lengths) if i in held]
            placement = "least_repeated"
        else:
            train, hold = split(lengths, spec.holdout, seed)
            placement = "episodes"
    heldout = describe(states, train, hold, scale, placement, fps)
    heldout = replace(heldout, period_s=period, periodicity=r, period_source=source, end_share=end_share)
    return train, hold, heldout


def _one_episode(
    spec: CalibrationSpec, x: np.ndarray, fps: float, scale: np.ndarray
) -> tuple[list[Window], list[Window], str, float | None]:
    """Fitted windows, the held-out one, its placement and the end split's repeat share, for one episode."""
    n = len(x)
    if spec.holdout_window:
        t0, t1 = spec.holdout_window
        t = np.arange(n) / fps
        rows = np.flatnonzero((t >= t0) & (t < t1))
        if rows.size == 0:
            raise SpecError(
                f"spec field 'holdout': the window [{t0:g}, {t1:g}] s holds no frame of the log (0-{t[-1]:.3g} s)"
            )
        start, stop, placement = int(rows[0]), int(rows[-1]) + 1, "window"
    else:
        length = n - int(round((1.0 - spec.holdout) * n))  # as `bench.replay.data.split` cuts the end
        if 0 < length < n and spec.holdout_at == "least_repeated":
            start, stop, _ = novelty.least_repeated_window(x, length, 0, scale=scale)
            placement = "least_repeated"
        else:
            start, stop, placement = n - length, n, "end"
    train = [Window(0, a, b) for a, b in ((0, start), (stop, n)) if b - a >= 2]  # a horizon needs 2 frames
    fitted = sum(len(w) for w in train)
    if fitted == 0 or stop - start < 2:
        what = (
            f"leaves {fitted} frames to fit"
            if fitted == 0
            else f"holds out {stop - start} frame{'' if stop - start == 1 else 's'}"
        )
        raise SpecError(
            f"spec field 'holdout': holding out {start / fps:.3g}-{(stop - 1) / fps:.3g} s of a "
            f"{(n - 1) / fps:.3g} s log {what}; hold out at least 2 frames and leave at least 2 to fit"
        )
    cut = n - (stop - start)
    end_share = novelty.repeat_share(novelty.nearest(x[:cut], x[cut:], scale)[0]) if cut > 0 else None
    return train, [Window(0, start, stop)], placement, end_share


def describe(
    states: list[np.ndarray],
    train: list[Window],
    hold: list[Window],
    scale: np.ndarray,
    placement: str,
    fps: float,
) -> novelty.Heldout:
    """The `Heldout` of a split: its repeat share and windows (period and end share left to the caller)."""
    fit_x = np.concatenate([states[w.episode][w.start : w.stop] for w in train])
    held_x = np.concatenate([states[w.episode][w.start : w.stop] for w in hold])
    return novelty.Heldout(
        placement=placement,
        repeat_share=novelty.repeat_share(novelty.nearest(fit_x, held_x, scale)[0]),
        windows=[{"episode": w.episode, "start_s": w.start / fps, "stop_s": (w.stop - 1) / fps} for w in hold],
    )


def heldout_of(rec: Recording) -> novelty.Heldout:
    """The recording's `Heldout`: the one its split was chosen with, else one measured from its windows
    (a plant built by hand: placement 'end' or 'episodes', as `bench.replay.data.split` places them)."""
    if isinstance(rec, SplitRecording) and rec.heldout is not None:
        return rec.heldout
    states = [states_of(rec, w) for w in rec.episodes()]
    if not rec.holdout or not rec.train:
        return novelty.Heldout(placement="none", repeat_share=0.0)
    placement = "end" if rec.n_episodes == 1 else "episodes"
    heldout = describe(states, rec.train, rec.holdout, novelty.spread(np.concatenate(states)), placement, rec.fps)
    period, r = novelty.period_of(states[int(np.argmax([len(x) for x in states]))], rec.fps)
    return replace(heldout, period_s=period, periodicity=r)
