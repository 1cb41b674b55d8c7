"""Held-out data that is new: how much of it repeats what was fitted, where the least repeated stretch is,
and what memory alone scores on it.

A held-out error says how well a model generalises only if the held-out data are not a repeat of the
fitted data. Excitations are often periodic (a Fourier series repeats every period), and a time split
of such a log holds out states the fit has already seen: there, replaying the measured signal from one
period earlier beats any model. So every calibration

1. measures the **repeat share** of its held-out samples: a held-out state (positions and velocities,
   each divided by its spread over the log) repeats the fitted data when a fitted state lies within
   `REPEAT_TOL` of it (root mean square over the coordinates, `nearest`);
2. detects the excitation's **period** (`period_of`: the first autocorrelation peak of at least
   `PERIOD_MIN_R` after the signal has decorrelated);
3. holds out, by default, the **least repeated** stretch (`least_repeated_window` for one episode,
   `least_repeated_episodes` for several: bands of share counted from the least repeated episode's), with a
   guard band around it that no fitted sample may use
   (a zero-phase filter spans the split by about its own length), and says when even that stretch
   repeats more than `NOTHING_NEW` of what was fitted;
4. scores a **repeat baseline** on the same held-out samples (`nearest_signal`, `period_signal`,
   `nearest_motion`): the measured signal of the nearest fitted state, or of one period earlier. A model
   is called better only if it beats it.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import TypedDict

import numpy as np

from bench.core.errors import DataError, SpecError
from bench.replay.data import Window, split

REPEAT_TOL = 0.05  # a held-out state within 5% of every coordinate's spread (RMS) of a fitted one repeats it
PERIOD_MIN_R = 0.9  # autocorrelation at a lag above which the excitation repeats itself with that period
DECORRELATED_R = 0.5  # ... once it has first fallen below this (a slow signal is not a periodic one)
NOTHING_NEW = 0.5  # held-out data that repeat more than this share of the fitted data hold nothing new
PLACEMENTS = ("least_repeated", "end", "episodes")


def spread(x: np.ndarray) -> np.ndarray:
    """Per-column standard deviation, never zero (a constant column divides by 1)."""
    s = np.asarray(x, dtype=np.float64).std(axis=0)
    return np.where(s > 1e-12, s, 1.0)


def nearest(fitted: np.ndarray, held: np.ndarray, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance of each held-out row to its nearest fitted row (RMS over columns of the difference divided by
    `scale`) and that row's index."""
    from scipy.spatial import cKDTree  # scipy: loaded only when a split is measured

    if len(fitted) == 0:
        return np.full(len(held), np.inf), np.full(len(held), -1)
    d, idx = cKDTree(fitted / scale).query(held / scale)
    return np.asarray(d) / np.sqrt(fitted.shape[1]), np.asarray(idx)


def repeat_share(dist: np.ndarray, tol: float = REPEAT_TOL) -> float:
    """Share of held-out rows within `tol` of a fitted one."""
    return float(np.mean(dist <= tol)) if len(dist) else 0.0


def period_of(x: np.ndarray, rate: float, min_lag_s: float = 0.05) -> tuple[float | None, float]:
    """(period in seconds, autocorrelation there) of a multichannel signal, or (None, best r) when it has none.

    The autocorrelation at lag L is the normalised inner product of x[t] and x[t + L] over their overlap
    (each channel standardised), for lags that leave at least a quarter of the signal to overlap; the
    period is the first local peak at or above PERIOD_MIN_R that follows a dip below DECORRELATED_R.
    """
    x = np.asarray(x, dtype=np.float64)
    n = len(x)
    lo, hi = max(1, int(round(min_lag_s * rate))), int(n * 0.75)
    if hi <= lo + 2:
        return None, float("nan")
    z = (x - x.mean(axis=0)) / spread(x)
    size = 1 << int(np.ceil(np.log2(2 * n)))
    f = np.fft.rfft(z, size, axis=0)
    cross = np.fft.irfft(np.sum(f * np.conj(f), axis=1), size)[:n]  # sum over channels of sum_t z[t] z[t + L]
    sq = np.concatenate([[0.0], np.cumsum(np.sum(z * z, axis=1))])
    lags = np.arange(n)
    head = sq[n - lags]  # sum of |z|^2 over t < n - L
    tail = sq[n] - sq[lags]  # over t >= L
    r = cross / np.sqrt(np.maximum(head * tail, 1e-300))
    below = np.flatnonzero(r[: hi + 1] < DECORRELATED_R)
    if below.size == 0:
        return None, float(np.max(r[lo:hi]))
    start = max(lo, int(below[0]))
    seg = r[start:hi]
    peaks = np.flatnonzero((seg[1:-1] >= seg[:-2]) & (seg[1:-1] >= seg[2:]) & (seg[1:-1] >= PERIOD_MIN_R)) + 1
    if peaks.size == 0:
        return None, float(np.max(seg)) if seg.size else float("nan")
    lag = start + int(peaks[0])
    return lag / rate, float(r[lag])


def least_repeated_window(
    x: np.ndarray, length: int, guard: int, tol: float = REPEAT_TOL, scale: np.ndarray | None = None
) -> tuple[int, int, float]:
    """(start, stop, repeat share) of the held-out window of `length` rows that repeats the rest least.

    Candidate starts every tenth of the window (and the very end); the rest, less `guard` rows on either
    side of the window, is what a fit would see. Ties go to the later start (the plain time split).
    """
    n = len(x)
    if length <= 0 or length >= n:
        raise DataError(f"a held-out window of {length} samples leaves nothing to fit in a log of {n}")
    scale = spread(x) if scale is None else scale
    step = max(1, length // 10)
    starts = sorted(set(range(0, n - length + 1, step)) | {n - length})
    best: tuple[float, int] | None = None
    for s in starts:
        keep = np.ones(n, bool)
        keep[max(0, s - guard) : min(n, s + length + guard)] = False
        if not keep.any():
            continue
        share = repeat_share(nearest(x[keep], x[s : s + length], scale)[0], tol)
        if best is None or share < best[0] - 1e-12 or abs(share - best[0]) <= 1e-12:
            best = (share, s)
    if best is None:
        raise DataError(f"a held-out window of {length} samples with a guard of {guard} leaves nothing to fit")
    return best[1], best[1] + length, best[0]


def episode_shares(xs: list[np.ndarray], tol: float = REPEAT_TOL) -> list[float]:
    """Each episode's repeat share against all the other episodes (states over the spread of them all)."""
    scale = spread(np.concatenate(xs))
    out = []
    for i, x in enumerate(xs):
        rest = np.concatenate([y for j, y in enumerate(xs) if j != i])
        out.append(repeat_share(nearest(rest, x, scale)[0], tol))
    return out


def least_repeated_episodes(
    xs: list[np.ndarray], n_hold: int, seed: int, tol: float = REPEAT_TOL, band: float = 0.1
) -> list[int]:
    """The `n_hold` episodes whose states repeat the other episodes least, in bands of `band` counted up from the
    least repeated episode's share; within a band the seeded order decides (as a plain seeded split would).

    Bands, not fixed tenths (where 0.045 and 0.065 would fall either side of 0.05 and rank apart): episodes
    whose shares differ by less than `band` from the lowest are all equally new, so a log whose episodes are
    all new keeps the plain seeded split (`bench.replay.data.split`)."""
    shares = episode_shares(xs, tol)
    low = min(shares)
    order = np.random.default_rng(seed).permutation(len(xs))
    rank = {int(e): i for i, e in enumerate(order)}
    return sorted(range(len(xs)), key=lambda i: (int((shares[i] - low) / band + 1e-9), rank[i]))[:n_hold]


def nearest_signal(
    fit_x: np.ndarray, fit_y: np.ndarray, held_x: np.ndarray, scale: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Memory as a predictor: each held-out row gets the signal of its nearest fitted state (and the distance)."""
    dist, idx = nearest(fit_x, held_x, scale)
    return fit_y[idx], dist


def period_signal(y: np.ndarray, t: np.ndarray, period: float, fitted: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Memory of one period: the measured signal one `period` earlier (linear interpolation in time) where that
    instant lies in the fitted data, NaN elsewhere. `t` is one episode's clock, `fitted` its fitted mask."""
    out = np.full((len(rows), y.shape[1]), np.nan)
    back = t[rows] - period
    pos = np.interp(back, t, np.arange(len(t)), left=-1.0, right=-1.0)
    ok = pos >= 0
    i0 = np.floor(pos[ok]).astype(int)
    i1 = np.minimum(i0 + 1, len(t) - 1)
    w = (pos[ok] - i0)[:, None]
    good = fitted[i0] & fitted[i1]
    vals = y[i0] * (1 - w) + y[i1] * w
    sub = np.flatnonzero(ok)
    out[sub[good]] = vals[good]
    return out


def nearest_motion(
    q: np.ndarray,
    feats: np.ndarray,
    hold_starts: np.ndarray,
    fit_starts: np.ndarray,
    k: int,
    scale: np.ndarray,
) -> np.ndarray:
    """Memory of motion: each held-out horizon (k frames from a start) continues like the horizon of the nearest
    fitted start, shifted to begin at the logged position: (len(hold_starts), k, n) positions."""
    _, idx = nearest(feats[fit_starts], feats[hold_starts], scale)
    src = fit_starts[idx]
    steps = np.arange(k)
    return q[hold_starts][:, None, :] + q[src[:, None] + steps] - q[src][:, None, :]


class HeldWindow(TypedDict):
    """One held-out stretch of an episode, in seconds of its clock."""

    episode: int
    start_s: float
    stop_s: float


@dataclass
class Heldout:
    """Where the held-out data came from and how new they are (calibration.json's `heldout` section)."""

    placement: str  # least_repeated | end | episodes | window
    repeat_share: float  # share of held-out samples that repeat a fitted one
    tol: float = REPEAT_TOL
    period_s: float | None = None  # the excitation's period (declared or detected), None when it has none
    periodicity: float | None = None  # autocorrelation at that period
    period_source: str = "detected"  # detected | declared (spec field 'period')
    guard_s: float = 0.0  # seconds around the held-out data that no fitted sample uses
    windows: list[HeldWindow] = field(default_factory=list)
    end_share: float | None = None  # the repeat share a plain time split (the last share of time) would have had

    @property
    def nothing_new(self) -> bool:
        return self.repeat_share > NOTHING_NEW

    def sentence(self) -> str:
        """One line for the report and the command's output."""
        where = {
            "least_repeated": "the least repeated stretch of the log",
            "end": "the last share of time",
            "episodes": "a seeded share of episodes",
            "window": "the window the spec names",
        }.get(self.placement, self.placement)
        per = (
            f"; the excitation repeats every {self.period_s:.3g} s ({self.period_source})"
            if self.period_s
            else "; no periodic excitation detected"
        )
        end = (
            f" (a plain time split would have held out {100 * self.end_share:.0f}% repeats)"
            if self.end_share is not None and self.placement != "end"
            else ""
        )
        head = f"held out: {where}, {100 * self.repeat_share:.0f}% of it repeats fitted states{end}{per}"
        if self.nothing_new:
            head += "; THE LOG HOLDS NOTHING NEW: held-out errors measure memory, not generalisation"
        return head

    def to_json(self) -> dict[str, object]:
        return {
            "placement": self.placement,
            "repeat_share": self.repeat_share,
            "repeat_tol": self.tol,
            "nothing_new": self.nothing_new,
            "period_s": self.period_s,
            "periodicity": self.periodicity,
            "period_source": self.period_source if self.period_s else None,
            "guard_s": self.guard_s,
            "windows": self.windows,
            "end_split_repeat_share": self.end_share,
            "method": (
                "a held-out state (positions and velocities over their spread) repeats the fitted data when a "
                f"fitted state lies within {self.tol:g} of it (RMS over coordinates)"
            ),
            "sentence": self.sentence(),
        }


def choose(
    states: list[np.ndarray],
    clocks: list[np.ndarray],
    *,
    share: float,
    window: tuple[float, float] | None,
    at: str,
    guard: int,
    seed: int,
    period: float | None,
    min_fit: int = 2,
) -> tuple[list[Window], list[Window], Heldout]:
    """Fitted and held-out windows (rows of each episode) and how new the held-out ones are: the one split of
    every calibration (the arm path's rows are filtered samples, `guard` > 0; the forward path's raw frames).

    `states` are each episode's [q, dq] rows and `clocks` their times (s). One episode: the `window` of time
    when given, else `share` of it where it repeats the rest least (`at: least_repeated`) or at the end
    (`at: end`), the fitted windows before and after it less `guard` rows; several episodes: the least
    repeated ones (`least_repeated_episodes`), or a seeded share (`at: episodes`/`end`, `bench.replay.data.split`).
    `period` (declared, s): every episode must hold one; else it is detected. Bad choices are one line naming
    the spec field: a window without samples, one that leaves fewer than `min_fit` rows to fit, a window in a
    log of several episodes, an episode shorter than its declared period.
    """
    lengths = [len(x) for x in states]
    scale = spread(np.concatenate(states))
    longest = int(np.argmax(lengths))
    step = float(np.median(np.diff(clocks[longest]))) if lengths[longest] > 1 else 1.0
    if period is not None:
        short = [i for i, t in enumerate(clocks) if t[-1] - t[0] < period]
        if short:
            i = short[0]
            raise DataError(
                f"episode {i} holds {clocks[i][-1] - clocks[i][0]:.3g} s, less than one period of its excitation "
                f"(spec field 'period': {period:g} s): a log must hold at least one whole period"
            )
        r: float | None = None
        source = "declared"
    else:
        period, r = period_of(states[longest], 1.0 / step)
        source = "detected"
    end_share = None
    if len(states) == 1:
        x, t, n = states[0], clocks[0], lengths[0]
        if window:
            rows = np.flatnonzero((t >= window[0]) & (t < window[1]))
            if rows.size == 0:
                raise SpecError(
                    f"spec field 'holdout': the window [{window[0]:g}, {window[1]:g}] s holds no sample of the log "
                    f"({t[0]:.3g}-{t[-1]:.3g} s)"
                )
            start, stop, placement = int(rows[0]), int(rows[-1]) + 1, "window"
        else:
            length = n - int(round((1.0 - share) * n))  # as `bench.replay.data.split` cuts the end
            if 0 < length < n and at == "least_repeated":
                start, stop, _ = least_repeated_window(x, length, guard, scale=scale)
                placement = "least_repeated"
            else:
                start, stop, placement = n - length, n, "end"
        train = [Window(0, a, b) for a, b in ((0, max(0, start - guard)), (min(n, stop + guard), n)) if b - a >= 2]
        fitted = sum(len(w) for w in train)
        if fitted < min_fit or stop - start < 2:
            what = f"leaves {fitted} samples to fit" if fitted < min_fit else f"holds out {stop - start} sample(s)"
            raise SpecError(
                f"spec field 'holdout': holding out {t[start]:.3g}-{t[stop - 1]:.3g} s of a {t[-1]:.3g} s log "
                f"(guards of {guard} samples) {what}; hold out at least 2 samples and leave at least {min_fit} to fit"
            )
        hold = [Window(0, start, stop)]
        end_keep = np.ones(n, bool)
        end_keep[max(0, n - (stop - start) - guard) :] = False
        if end_keep.any():
            end_share = repeat_share(nearest(x[end_keep], x[n - (stop - start) :], scale)[0])
    else:
        if window:
            raise SpecError(
                "spec field 'holdout': a time window needs a one-episode log; this one has "
                f"{len(states)} episodes (give a share instead)"
            )
        if at == "least_repeated":
            n_hold = min(len(states) - 1, max(1, int(round(share * len(states)))))
            held = set(least_repeated_episodes(states, n_hold, seed))
            train = [Window(i, 0, n) for i, n in enumerate(lengths) if i not in held]
            hold = [Window(i, 0, n) for i, n in enumerate(lengths) if i in held]
            placement = "least_repeated"
        else:
            train, hold = split(lengths, share, seed)
            placement = "episodes"
    heldout = replace(
        measured(states, clocks, train, hold, placement, scale),
        period_s=period,
        periodicity=r,
        period_source=source,
        guard_s=guard * step if len(states) == 1 else 0.0,
        end_share=end_share,
    )
    return train, hold, heldout


def measured(
    states: list[np.ndarray],
    clocks: list[np.ndarray],
    train: list[Window],
    hold: list[Window],
    placement: str,
    scale: np.ndarray,
) -> Heldout:
    """The `Heldout` of a split already made: its repeat share and its windows in seconds (period, guard and
    the end split's share left at their defaults, for `choose` or a caller that knows them)."""
    fit_x = np.concatenate([states[w.episode][w.start : w.stop] for w in train])
    held_x = np.concatenate([states[w.episode][w.start : w.stop] for w in hold])
    return Heldout(
        placement=placement,
        repeat_share=repeat_share(nearest(fit_x, held_x, scale)[0]),
        windows=[
            {
                "episode": w.episode,
                "start_s": float(clocks[w.episode][w.start]),
                "stop_s": float(clocks[w.episode][w.stop - 1]),
            }
            for w in hold
        ],
    )


def horizon_starts(offsets: np.ndarray, windows: list[Window], k: int) -> np.ndarray:
    """Global start frames of every k-frame horizon that fits inside one of `windows` (its k frames after the
    start included): where memory may look up a fitted motion (`nearest_motion`)."""
    parts = [np.arange(offsets[w.episode] + w.start, offsets[w.episode] + w.stop - k) for w in windows]
    return np.concatenate([*parts, np.zeros(0, dtype=np.int64)]).astype(np.int64)
