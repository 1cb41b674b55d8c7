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
from bench.replay.data import Recording, Window
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
    held-out ones are (`bench.calibrate.novelty.choose`).

    The guard band is 0 frames: the forward path fits no filtered signal (a velocity estimated from
    positions is a ~20 ms derivative that only starts simulated horizons; nothing fitted smooths across
    the split), so the frames right before and after a held-out window are fitted; each fitted window of an
    episode gets its own horizons (`bench.replay.simulate.horizons`).
    """
    return novelty.choose(
        states,
        [np.arange(len(x)) / fps for x in states],
        share=spec.holdout,
        window=spec.holdout_window,
        at=spec.holdout_at,
        guard=0,
        seed=seed,
        period=spec.period,
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
    clocks = [np.arange(len(x)) / rec.fps for x in states]
    heldout = novelty.measured(
        states, clocks, rec.train, rec.holdout, placement, novelty.spread(np.concatenate(states))
    )
    period, r = novelty.period_of(states[int(np.argmax([len(x) for x in states]))], rec.fps)
    return replace(heldout, period_s=period, periodicity=r)
