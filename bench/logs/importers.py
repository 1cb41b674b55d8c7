"""Importers from other log formats to a `LogDataset`: CSV and MATLAB .mat (RLDS: `bench.logs.rlds`).

Every importer returns the same in-memory form as `read_dataset` (see `bench.logs.dataset`):
`observation.state` and `action` as float32 (T, D) with element names, `timestamp` in seconds
from the episode start, and, when the source has a time column, the source's absolute time as
an int64 nanosecond feature `time_ns` (T, 1) — float32 seconds lose precision on long logs.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from bench.core.errors import DataError, did_you_mean
from bench.logs.dataset import LogDataset, first_bad_row, from_arrays
from bench.logs.resample import check_times
from bench.logs.resample import resample as resample_columns

TIME_NAMES = ("t", "time", "Time", "timestamp")


def _as_list(value: str | Sequence[str] | None) -> list[str] | None:
    if value is None:
        return None
    return [value] if isinstance(value, str) else [str(v) for v in value]


def _fps_from_time(t: np.ndarray, where: str, column: str) -> float:
    dt = np.diff(t)
    if dt.size == 0:
        raise DataError(f"{where}: column {column!r} has one sample; pass fps= to set the frame rate")
    fps = 1.0 / float(np.median(dt))
    # A nominal rate: sample clocks jitter (EMPS: 1000.016 Hz by median step), the true times
    # stay in `timestamp` / `time_ns`. Snap to an integer within 0.1 %, as lerobot expects ints.
    return float(round(fps)) if abs(fps - round(fps)) <= 1e-3 * fps else round(fps, 6)


def _time_features(t: np.ndarray) -> dict[str, np.ndarray]:
    """`timestamp` (seconds from the first sample, float32) and `time_ns` (absolute, int64 ns)."""
    t = np.asarray(t, dtype=np.float64)
    return {"timestamp": (t - t[0]).astype(np.float32), "time_ns": np.round(t * 1e9).astype(np.int64)[:, None]}


# ----------------------------------------------------------------------------- CSV


F32_MAX = float(np.finfo(np.float32).max)


def import_csv(
    path: str | os.PathLike,
    *,
    state: str | Sequence[str] | None = None,
    action: str | Sequence[str] | None = None,
    time: str | None = None,
    fps: float | None = None,
    task: str = "default",
    episode: str | None = None,
    robot_type: str | None = None,
    delimiter: str = ",",
    velocity: str | Sequence[str] | None = None,
    effort: str | Sequence[str] | None = None,
    resample: float | None = None,
) -> LogDataset:
    """Import a CSV file with a header row.

    Args:
        path: the CSV file.
        state: columns for `observation.state` (default: every numeric column not used otherwise).
        action: columns for `action` (default: none).
        time: column with the sample time in seconds; gives `timestamp`, `time_ns` and, without
            `fps`, the nominal frame rate (1 / median step, snapped to an integer within 0.1 %).
            Without it, `timestamp` = frame / fps.
        fps: frame rate in Hz (required when there is no time column).
        task: task string of every episode.
        episode: column whose value splits the rows into episodes (default: one episode).
        robot_type: stored in info.json.
        delimiter: field separator.
        velocity: columns for `observation.velocity` (joint velocities as the robot logged them).
        effort: columns for `observation.effort` (measured joint torques or currents, LeRobot's name).
        resample: put an irregular clock onto a uniform grid at this rate in Hz (needs `time`), by
            linear interpolation (`bench.logs.resample`: the method, and gaps it refuses); the
            episode's meta records what was done under "resampled".
    """
    import pyarrow as pa  # pyarrow: loaded only when a dataset is read or written
    import pyarrow.csv as pacsv  # pyarrow: loaded only when a dataset is read or written

    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: file is missing")
    try:
        table = pacsv.read_csv(
            path,
            parse_options=pacsv.ParseOptions(delimiter=delimiter),
            convert_options=pacsv.ConvertOptions(null_values=[""]),  # "nan" stays a NaN float, caught below
        )
    except (pa.ArrowException, OSError) as exc:
        raise DataError(f"{path}: cannot parse CSV: {str(exc).splitlines()[0]}") from None
    columns = table.column_names
    if table.num_rows == 0:
        raise DataError(f"{path}: no data rows")
    twice = next((c for i, c in enumerate(columns) if c in columns[:i]), None)
    if twice is not None:
        raise DataError(f"{path}: column {twice!r} appears twice in the header; give every column its own name")

    def column(name: str, numeric: bool = True) -> np.ndarray:
        if name not in columns:
            hint = did_you_mean(name, columns)
            raise DataError(f"{path}: column {name!r} not found; columns: {', '.join(columns)}.{hint}")
        col = table.column(name)
        if col.null_count:
            row = first_bad_row(np.asarray(col.is_null().to_numpy(zero_copy_only=False)))
            raise DataError(f"{path}: column {name!r} has an empty cell at row {row}")
        if numeric and not (pa.types.is_integer(col.type) or pa.types.is_floating(col.type)):
            raise DataError(f"{path}: column {name!r} is {col.type}, not numeric")
        return col.to_numpy() if numeric else np.asarray(col.to_pylist(), dtype=object)

    state_cols, action_cols = _as_list(state), _as_list(action) or []
    extra = {"observation.velocity": _as_list(velocity) or [], "observation.effort": _as_list(effort) or []}
    used = {c for c in (time, episode) if c} | {c for cols in extra.values() for c in cols}
    if state_cols is None:
        numeric = [
            c
            for c in columns
            if pa.types.is_integer(table.column(c).type) or pa.types.is_floating(table.column(c).type)
        ]
        state_cols = [c for c in numeric if c not in used and c not in action_cols]
        text = [c for c in columns if c not in numeric and c not in used]
        if text:
            raise DataError(
                f"{path}: column {text[0]!r} is {table.column(text[0]).type}, not numeric; pass "
                "state=[...] (and action=[...]) to choose the columns to import"
            )
    if not state_cols and not action_cols:
        raise DataError(f"{path}: no state or action columns; pass state=[...] and/or action=[...]")
    for c in state_cols + action_cols + [c for cols in extra.values() for c in cols]:
        column(c)
    t_all = column(time).astype(np.float64) if time else None
    if t_all is None and fps is None:
        raise DataError(f"{path}: field 'fps' is required when no time column is given (time=COLUMN)")
    if resample is not None and t_all is None:
        raise DataError(f"{path}: field 'resample' needs a time column (time=COLUMN) to resample from")

    if episode:
        ids = column(episode, numeric=False)
        keys = list(dict.fromkeys(ids.tolist()))
        groups = [np.flatnonzero(ids == k) for k in keys]
    else:
        keys, groups = [None], [np.arange(table.num_rows)]

    episodes: list[dict[str, np.ndarray]] = []
    meta: list[dict] = []
    rate = fps
    for key, rows in zip(keys, groups):
        data: dict[str, np.ndarray] = {}
        if state_cols:
            data["observation.state"] = np.stack([column(c)[rows] for c in state_cols], axis=1)
        if action_cols:
            data["action"] = np.stack([column(c)[rows] for c in action_cols], axis=1)
        for feature, cols in extra.items():
            if cols:
                data[feature] = np.stack([column(c)[rows] for c in cols], axis=1)
        names_of = {"observation.state": state_cols, "action": action_cols, **extra}
        for name, arr in data.items():
            cols = names_of[name]
            bad = first_bad_row(~np.isfinite(arr.astype(np.float64)))
            if bad >= 0:
                c = next(c for j, c in enumerate(cols) if not np.isfinite(float(arr[bad, j])))
                raise DataError(f"{path}: column {c!r} is NaN or inf at row {int(rows[bad])}")
            big = first_bad_row(np.abs(arr.astype(np.float64)) > F32_MAX)
            if big >= 0:
                c = next(c for j, c in enumerate(cols) if abs(float(arr[big, j])) > F32_MAX)
                raise DataError(
                    f"{path}: column {c!r} is {float(arr[big, cols.index(c)]):g} at row {int(rows[big])}, "
                    "beyond what float32 holds (3.4e38)"
                )
        info: dict = {"source": path.name, **({"episode": key} if key is not None else {})}
        if t_all is not None:
            t = t_all[rows]
            check_times(t, str(path), time, offset=int(rows[0]))  # type: ignore[arg-type]
            if resample is not None:
                t, data, info["resampled"] = resample_columns(t, data, resample, where=str(path), column=str(time))
                rate = float(resample)
            data.update(_time_features(t))
            if rate is None:
                rate = _fps_from_time(t, str(path), time)  # type: ignore[arg-type]
        episodes.append(data)
        meta.append(info)
    names = {k: v for k, v in (("observation.state", state_cols), ("action", action_cols), *extra.items()) if v}
    assert rate is not None  # fps given, or measured from the time column above
    return from_arrays(
        episodes,
        fps=float(rate),
        task=task,
        names=names,  # type: ignore[arg-type]
        robot_type=robot_type,
        meta=meta,
    )


# ----------------------------------------------------------------------------- MATLAB


def import_mat(
    path: str | os.PathLike,
    mapping: dict[str, str | Sequence[str]] | None = None,
    fps: float | None = None,
    *,
    time: str | None = None,
    velocity: bool = False,
    task: str = "default",
    robot_type: str | None = None,
) -> LogDataset:
    """Import a MATLAB v5/v7 .mat file (scipy.io.loadmat) as a one-episode dataset.

    Example (EMPS: position `qm`, drive command `vir`, time `t`):
        import_mat("DATA_EMPS.mat", {"observation.state": ["qm"], "action": ["vir"]}, velocity=True)
        # observation.state = [qm, qm_dot], action = [vir], fps 1000, meta["mat"] = {gtau, kp, kv}

    Args:
        path: the .mat file.
        mapping: feature name -> variable names, concatenated as columns (a (T, k) variable adds k
            columns). Default: every length-T variable except time becomes `observation.state`.
        fps: frame rate; default 1 / median time step (snapped to an integer within 0.1 %).
        time: the time variable in seconds (default: the first of t, time, Time present).
        velocity: append the time derivative (central differences) of each `observation.state`
            column, named `<var>_dot`, for logs that measure position only.
        task: the episode's task string.
        robot_type: stored in info.json.

    Scalar variables (e.g. gains) go to the episode's `meta["mat"]`.
    """
    import scipy.io  # scipy: loaded only when this estimate is computed

    path = Path(path)
    if not path.is_file():
        raise DataError(f"{path}: file is missing")
    try:
        raw = scipy.io.loadmat(str(path))
    except NotImplementedError:
        raise DataError(f"{path}: MATLAB v7.3 (HDF5) files are not supported; save with -v7") from None
    except Exception as exc:  # scipy raises ValueError/TypeError/MatReadError on bad files
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise DataError(f"{path}: cannot read .mat file: {reason}") from None
    variables = {k: v for k, v in raw.items() if not k.startswith("__")}
    numeric = {k: np.asarray(v) for k, v in variables.items() if isinstance(v, np.ndarray) and v.dtype.kind in "biuf"}
    if time is None:
        time = next((n for n in TIME_NAMES if n in numeric and numeric[n].size > 1), None)
    elif time not in numeric:
        hint = did_you_mean(time, variables)
        raise DataError(f"{path}: time variable {time!r} not found; variables: {', '.join(variables)}.{hint}")
    t = numeric[time].astype(np.float64).reshape(-1) if time else None
    if t is None and fps is None:
        raise DataError(f"{path}: field 'fps' is required: no time variable ({', '.join(TIME_NAMES)}) found")
    if t is not None:
        check_times(t, str(path), time)  # type: ignore[arg-type]
        length = len(t)
    else:
        sizes = [max(v.shape) for v in numeric.values() if v.size > 1 and v.ndim <= 2]
        if not sizes:
            raise DataError(f"{path}: no vector variables")
        length = max(sizes)

    def columns(name: str) -> tuple[np.ndarray, list[str]]:
        if name not in variables:
            hint = did_you_mean(name, variables)
            raise DataError(f"{path}: variable {name!r} not found; variables: {', '.join(variables)}.{hint}")
        if name not in numeric or numeric[name].ndim > 2:
            raise DataError(f"{path}: variable {name!r} is not a numeric vector or matrix")
        v = numeric[name].astype(np.float64)
        if v.ndim == 1:
            v = v[:, None]
        if v.shape[0] != length and v.shape[1] == length:
            v = v.T
        if v.shape[0] != length:
            like = time or "the longest vector"
            shape = numeric[name].shape
            raise DataError(f"{path}: variable {name!r} has shape {shape}; expected {length} samples like {like!r}")
        row = first_bad_row(~np.isfinite(v))
        if row >= 0:
            raise DataError(f"{path}: variable {name!r} is NaN or inf at sample {row}")
        names = [name] if v.shape[1] == 1 else [f"{name}[{j}]" for j in range(v.shape[1])]
        return v, names

    if mapping is None:
        vectors = [k for k, v in numeric.items() if k != time and v.size > 1 and length in v.shape and v.ndim <= 2]
        mapping = {"observation.state": vectors}
    data: dict[str, np.ndarray] = {}
    names: dict[str, list[str]] = {}
    for feature, var_names in mapping.items():
        blocks = [columns(v) for v in _as_list(var_names) or []]
        if not blocks:
            raise DataError(f"{path}: mapping for {feature!r} names no variables")
        data[feature] = np.concatenate([b[0] for b in blocks], axis=1)
        names[feature] = [n for b in blocks for n in b[1]]
    if velocity:
        if "observation.state" not in data:
            raise DataError(f"{path}: velocity=True needs an 'observation.state' mapping")
        x = data["observation.state"]
        spacing = t if t is not None else 1.0 / float(fps)  # type: ignore[arg-type]
        dx = np.gradient(x, spacing, axis=0)
        data["observation.state"] = np.concatenate([x, dx], axis=1)
        names["observation.state"] = names["observation.state"] + [f"{n}_dot" for n in names["observation.state"]]
    rate = fps
    if t is not None:
        data.update(_time_features(t))
        rate = rate or _fps_from_time(t, str(path), time)  # type: ignore[arg-type]
    big = next((k for k, v in numeric.items() if v.size and np.abs(v.astype(np.float64)).max() > F32_MAX), None)
    if big is not None:
        raise DataError(f"{path}: variable {big!r} holds values beyond what float32 holds (3.4e38)")
    scalars = {k: float(v.reshape(-1)[0]) for k, v in numeric.items() if v.size == 1}
    odd = next((k for k, v in scalars.items() if not np.isfinite(v)), None)
    if odd is not None:  # metadata is JSON: NaN / inf has no place there
        raise DataError(f"{path}: scalar variable {odd!r} is {scalars[odd]}; metadata must be finite (drop or fix it)")
    meta = {"source": path.name, **({"mat": scalars} if scalars else {})}
    assert rate is not None  # fps given, or measured from the time column above
    return from_arrays(
        [data],
        fps=float(rate),
        task=task,
        names=names,  # type: ignore[arg-type]
        robot_type=robot_type,
        meta=[meta],
    )
