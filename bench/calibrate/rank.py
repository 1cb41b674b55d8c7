"""Episodes ranked by sim-real surprise: what the calibrated model still gets wrong, episode by episode.

    bench logs rank DIR calibration=FILE [top=10] [out=FILE]

The calibrated model is rebuilt from its calibration.json (the spec and the final parameter
vector; for a suite calibration, the suite's robot in its scene) and every episode of DIR is
replayed from its first logged state under its logged commands to its end (`horizon=free_run`,
the default), or in k-step horizons re-initialised from the log (`horizon=k_step`, the
calibration's k). An episode's surprise is its position NRMSE (each joint's RMSE over the episode /
that joint's spread over the whole log, averaged over joints): high where the calibrated simulator
still parts from the robot, which is what to replay, inspect or collect more of next.
"""

from __future__ import annotations

from pathlib import Path
from typing import TypedDict

import numpy as np

from bench.calibrate.apply import read_calibration
from bench.calibrate.data import extract
from bench.calibrate.feedback import close_loop
from bench.calibrate.model import Candidate, Layout, Plant
from bench.calibrate.spec import parse_spec
from bench.calibrate.suite_robot import suite_plant
from bench.core.errors import DataError
from bench.logs import read_dataset
from bench.replay.simulate import free_runs, horizons, logged
from bench.replay.spec import load_model

HORIZONS = ("free_run", "k_step")


class Surprise(TypedDict):
    """One episode under the calibrated model: its position NRMSE over the logged spread, mean and per joint."""

    episode: int  # dataset index
    frames: int
    surprise: float
    per_joint: dict[str, float]


def _plant(doc: dict, logs: Path) -> tuple[Plant, list[int]]:
    """The plant of a calibration's model on the logs of DIR, and the dataset index of each episode in it."""
    if doc.get("apply"):  # a suite calibration: its robot in the suite's scene
        plant, info = suite_plant(doc["suite"]["name"], doc["apply"]["robot"], logs)
        if info["model_hash"] != doc["apply"]["model_hash"]:
            raise DataError(
                f"the calibration was fitted on another model of robot {doc['apply']['robot']!r} "
                f"(fingerprint {doc['apply']['model_hash'][:12]}, the suite's now "
                f"{info['model_hash'][:12]})"
            )
        return plant, info["suite"]["episodes"]

    spec = parse_spec({k: v for k, v in doc["spec"].items() if k != "source"}, base_dir="/")
    model = load_model(spec.model)
    ds = read_dataset(logs)
    rec = extract(spec, [ep.data for ep in ds.episodes], float(ds.fps), nq=model.nq, nv=model.nv, nu=model.nu)
    if spec.controller is not None:  # the calibration's own closed loop
        model, rec = close_loop(model, rec, *spec.controller)
    return Plant(spec, model, rec), [int(ep.index) for ep in ds.episodes]


def _layout(plant: Plant, labels: list[str]) -> Layout:
    """The layout whose parameter labels are `labels` (the declared slots, then each effect's)."""
    keys: list[str] = []
    for label in labels[len(plant.slots) :]:
        key = label.rsplit(".", 1)[0]
        if key not in keys:
            keys.append(key)
    cands, _ = plant.candidates(None)
    by_key = {c.key: c for c in cands}
    missing = [k for k in keys if k not in by_key]
    if missing:
        raise DataError(f"calibration effect {missing[0]!r} has no target in this model")
    active: list[Candidate] = [by_key[k] for k in keys]
    layout = Layout(plant, active)
    if layout.labels != labels:
        raise DataError("the calibration's parameters do not match its model (was it written by another version?)")
    return layout


def rank(calibration: str | Path, logs: str | Path, horizon: str = "free_run") -> dict[str, object]:
    """Every episode of `logs` with its surprise under the calibrated model, most surprising first."""
    if horizon not in HORIZONS:
        raise DataError(f"horizon={horizon!r}; valid: {', '.join(HORIZONS)}")
    path, _, doc = read_calibration(calibration)
    if not isinstance(doc, dict):
        doc = {}
    if doc.get("schema") != "bench.calibration/1" or "x" not in doc.get("fit", {}).get("final", {}):
        raise DataError(f"{path}: not a calibration result with its final parameters (bench.calibration/1)")
    logs = Path(logs).expanduser()
    if not logs.exists():
        raise DataError(f"logs folder {str(logs)!r} does not exist")
    plant, index = _plant(doc, logs)
    layout = _layout(plant, doc["fit"]["final"]["parameters"])
    x = np.array([np.nan if v is None else v for v in doc["fit"]["final"]["x"]], dtype=float)
    k = int(doc["errors"]["final"]["k"])
    rec = plant.rec
    segs = free_runs(rec, rec.episodes()) if horizon == "free_run" else horizons(rec, rec.episodes(), k)
    mask = segs.mask if segs.mask is not None else np.ones((len(segs), segs.length), bool)
    sim = plant.simulator()
    try:
        pred = sim.run([layout.realise(x)], segs)[0]
    finally:
        sim.close()
    nq = rec.qpos.shape[1]
    err = np.where(mask[..., None], pred[..., :nq] - logged(rec, segs)[..., :nq], 0.0)  # (n, length, nq)
    spread = np.maximum(rec.qpos.std(axis=0), 1e-12)
    episode = np.searchsorted(rec.offsets, segs.start, side="right") - 1
    rows: list[Surprise] = []
    for e in range(rec.n_episodes):
        sel = episode == e
        rmse = np.sqrt(np.sum(err[sel] ** 2, axis=(0, 1)) / max(int(mask[sel].sum()), 1))
        rows.append(
            {
                "episode": int(index[e]),
                "frames": int(rec.offsets[e + 1] - rec.offsets[e]),
                "surprise": float(np.mean(rmse / spread)),
                "per_joint": dict(zip(plant.joint_names, (rmse / spread).tolist())),
            }
        )
    rows.sort(key=lambda r: -r["surprise"])
    what = "free-run (open-loop, whole episode)" if horizon == "free_run" else f"k-step (k = {k} frames)"
    return {
        "schema": "bench.logs_rank/1",
        "calibration": str(path),
        "logs": str(logs),
        "horizon": horizon,
        "k": k,
        "statistic": f"{what} position NRMSE per episode under the calibrated model",
        "episodes": rows,
    }
