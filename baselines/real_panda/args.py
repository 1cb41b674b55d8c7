"""Keys, inputs and the policy population of `python -m baselines.real_panda`."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

ROOT = Path(__file__).resolve().parents[2]
SPEC = ROOT / "bench" / "calibrate" / "models" / "panda_gaz.yaml"
LOG = ROOT.parent / "shared" / "data" / "real" / "panda_gaz" / "trajectory_1.csv"
JOINT_COLS = {
    "state": [f"q{i}" for i in range(1, 8)],
    "velocity": [f"dq{i}" for i in range(1, 8)],
    "effort": [f"tau{i}" for i in range(1, 8)],
}
POLICIES: list[tuple[str, str, dict[str, Any]]] = [
    ("expert", "scripted", {}),
    ("expert-noise0.3", "baselines.expert_variants:ExpertVariant", {"noise": 0.3}),
    ("expert-noise0.6", "baselines.expert_variants:ExpertVariant", {"noise": 0.6}),
    ("expert-timid0.5", "baselines.expert_variants:ExpertVariant", {"scale": 0.5}),
    ("expert-weakgrip0.3", "baselines.expert_variants:ExpertVariant", {"grip": 0.3}),
    ("bc", "bc", {}),  # the committed checkpoint: 40 demonstrations per seen arm
    ("bc-small", "checkpoint", {}),  # trained here: 8 demonstrations per seen arm, a 64x64 MLP (checkpoint set below)
    ("random", "random", {}),
]
SWEEP_AXES = ("damping", "frictionloss", "link_mass")
REFERENCE = ROOT / "results" / "references" / "gaz_panda.json"  # Gaz et al.'s model on the held-out samples


@dataclass(frozen=True)
class Args:
    """Keys of `python -m baselines.real_panda`."""

    out: Optional[str] = None  # folder for README.md, population.json, friction.json and calibration/ (required)
    work: Optional[str] = None  # folder for the imported log and the runs (required; never inside out)
    log: str = str(LOG)  # the Panda CSV (Gaz et al.'s trajectory 1)
    episodes: int = 20  # episodes per policy and condition
    seed: int = 1  # run seed: the same initial states on the nominal and the calibrated robot
    workers: int = 2  # worker processes per run
    overwrite: bool = False  # replace an out folder this script wrote
