"""Logged trajectories as replay and calibration see them: arrays of shape (T, n), optionally split.

The core never reads files: callers hand it episodes as `dict[column, array]` (what
`bench.logs.Episode.data` holds) and a signal map (`bench.replay.spec`) picks the columns.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.core.errors import DataError, SpecError
from bench.replay.spec import SignalMap, SignalSpec


@dataclass(frozen=True)
class Window:
    """Frames [start, stop) of one episode."""

    episode: int
    start: int
    stop: int

    def __len__(self) -> int:
        return self.stop - self.start


@dataclass
class Recording:
    """Logged signals of all episodes (float64, concatenated in time) and a train / held-out split of them."""

    fps: float
    qpos: np.ndarray  # (N, nq)
    qvel: np.ndarray  # (N, nv), logged or estimated from qpos
    ctrl: np.ndarray  # (N, nu)
    inputs: np.ndarray | None  # (N, m) extra logged inputs
    offsets: np.ndarray  # (E + 1,) frame offset of each episode
    train: list[Window]
    holdout: list[Window]
    qvel_logged: bool
    input_names: tuple[str, ...] = ()

    @property
    def n_episodes(self) -> int:
        return len(self.offsets) - 1

    def episodes(self) -> list[Window]:
        """One window per whole episode."""
        return [Window(i, 0, int(self.offsets[i + 1] - self.offsets[i])) for i in range(self.n_episodes)]

    def frames(self, windows: list[Window]) -> np.ndarray:
        """Global frame indices covered by `windows`."""
        return np.concatenate(
            [np.arange(self.offsets[w.episode] + w.start, self.offsets[w.episode] + w.stop) for w in windows]
        )


def column(ep: dict[str, np.ndarray], sig: SignalSpec, where: str, i: int) -> np.ndarray:
    """The signal `sig` of episode `i` as float64 (T, len(index)); one line naming the field or rows otherwise."""
    if sig.column not in ep:
        valid = sorted(k for k, v in ep.items() if np.asarray(v).ndim in (1, 2))
        raise SpecError(
            f"spec field '{where}.column': column {sig.column!r} is not in the log (episode {i}); "
            f"valid: {', '.join(valid)}"
        )
    arr = np.asarray(ep[sig.column], dtype=np.float64)
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2:
        raise DataError(f"log column {sig.column!r} has shape {arr.shape}; expected (T,) or (T, D)")
    bad = [j for j in sig.index if j >= arr.shape[1]]
    if bad:
        raise SpecError(
            f"spec field '{where}.index': index {bad[0]} is out of range for column {sig.column!r} "
            f"of width {arr.shape[1]} (valid 0..{arr.shape[1] - 1})"
        )
    out = arr[:, list(sig.index)]
    bad = ~np.isfinite(out)
    if bad.any():
        rows, cols = np.nonzero(bad)
        j = int(cols[0])
        stretch = np.flatnonzero(bad[:, j])
        gap = np.flatnonzero(np.diff(stretch) > 1)
        end = int(stretch[gap[0]]) if gap.size else int(stretch[-1])
        raise DataError(
            f"log column {sig.column!r}[{sig.index[j]}] (episode {i}) is NaN or inf in rows {int(stretch[0])}..{end}: "
            "cut the episode there or fill the stretch before using it"
        )
    return out


def estimate_velocity(qpos: np.ndarray, fps: float) -> np.ndarray:
    """Velocity from positions by a Savitzky-Golay derivative over about 20 ms (quantised encoders)."""
    from scipy.signal import savgol_filter  # scipy: loaded only when this estimate is computed

    n = qpos.shape[0]
    win = max(5, int(round(0.02 * fps)) | 1)
    win = min(win, n - 1 if n % 2 == 0 else n)
    if win < 3:
        return np.gradient(qpos, 1.0 / fps, axis=0)
    return savgol_filter(qpos, win, polyorder=min(2, win - 1), deriv=1, delta=1.0 / fps, axis=0)


def split(lengths: list[int], holdout: float, seed: int) -> tuple[list[Window], list[Window]]:
    """Hold out a seeded share of episodes, or the last share of time when there is one episode."""
    if len(lengths) == 1:
        cut = int(round((1.0 - holdout) * lengths[0]))
        return [Window(0, 0, cut)], [Window(0, cut, lengths[0])]
    n_hold = min(len(lengths) - 1, max(1, int(round(holdout * len(lengths)))))
    hold = set(np.random.default_rng(seed).permutation(len(lengths))[:n_hold].tolist())
    train = [Window(i, 0, n) for i, n in enumerate(lengths) if i not in hold]
    test = [Window(i, 0, n) for i, n in enumerate(lengths) if i in hold]
    return train, test


def extract(
    spec: SignalMap,
    episodes: list[dict[str, np.ndarray]],
    fps: float,
    *,
    nq: int,
    nv: int,
    nu: int,
    holdout: float | None = None,
    seed: int = 0,
) -> Recording:
    """Pick the map's signals out of the episodes and check their widths against the model.

    With `holdout` (a share), the episodes are split into train and held out (`split`); without,
    every episode is a training window and nothing is held out.
    """
    if not episodes:
        raise DataError("the log holds no episodes")
    if not fps or fps <= 0:
        raise DataError(f"the log's fps must be positive; got {fps!r}")
    want = {"qpos": nq, "qvel": nv, "ctrl": nu}
    for key, n in want.items():
        sig = spec.signals.get(key)
        if sig is not None and len(sig.index) != n:
            raise SpecError(
                f"spec field 'signals.{key}.index' lists {len(sig.index)} columns; the model has "
                f"{'nq' if key == 'qpos' else 'nv' if key == 'qvel' else 'nu'}={n}"
            )
    parts: dict[str, list[np.ndarray]] = {"qpos": [], "qvel": [], "ctrl": [], "inputs": []}
    lengths = []
    for i, ep in enumerate(episodes):
        qpos = column(ep, spec.signals["qpos"], "signals.qpos", i)
        ctrl = column(ep, spec.signals["ctrl"], "signals.ctrl", i)
        t = len(qpos)
        if t < 4:
            raise DataError(f"episode {i} has {t} frames; replay and calibration need at least 4")
        if len(ctrl) != t:
            raise DataError(f"episode {i}: {len(ctrl)} ctrl frames but {t} qpos frames")
        if "qvel" in spec.signals:
            qvel = column(ep, spec.signals["qvel"], "signals.qvel", i)
        else:
            qvel = estimate_velocity(qpos, fps)
        parts["qpos"].append(qpos)
        parts["qvel"].append(qvel)
        parts["ctrl"].append(ctrl)
        if "inputs" in spec.signals:
            parts["inputs"].append(column(ep, spec.signals["inputs"], "signals.inputs", i))
        lengths.append(t)
    hold: list[Window] = []
    if holdout is None:
        train = [Window(i, 0, n) for i, n in enumerate(lengths)]
    else:
        train, hold = split(lengths, holdout, seed)
    sig_in = spec.signals.get("inputs")
    return Recording(
        fps=float(fps),
        qpos=np.concatenate(parts["qpos"]),
        qvel=np.concatenate(parts["qvel"]),
        ctrl=np.concatenate(parts["ctrl"]),
        inputs=np.concatenate(parts["inputs"]) if parts["inputs"] else None,
        offsets=np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64),
        train=train,
        holdout=hold,
        qvel_logged="qvel" in spec.signals,
        input_names=tuple(f"{sig_in.column}[{j}]" for j in sig_in.index) if sig_in else (),
    )
