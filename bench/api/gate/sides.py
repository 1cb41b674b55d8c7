"""The two sides of a regression gate's comparison (candidate and baseline): each a live run planned by
`bench.api.plan` or recorded episodes reused; how a live side is planned and run a look at a time, the checks
that the sides are pairable and played with the same settings, the inputs no output may overwrite, and what
the verdict says of each side (policy, checkpoint, provenance)."""

from __future__ import annotations

import json
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from bench.api import Plan, parse_run, plan, run
from bench.board.gate.inputs import (
    cells_of_jobs,
    cells_of_records,
    check_pairable,
    load_recorded,
)
from bench.core import config as config_mod
from bench.core.errors import ConfigError
from bench.core.provenance import checkpoint_provenance, portable
from bench.execution.local import LocalExecutor
from bench.records import EpisodeRecord

# run keys that must be equal for candidate and baseline (they decide which episodes are played)
SHARED_KEYS = (
    "suite",
    "seed",
    "horizon",
    "timeout",
    "robots",
    "tasks",
    "envs",
    "splits",
    "metric",
    "perturb",
    "env_id",
    "n_boot",
    "confidence",
    "allow_split_violation",
)


@dataclass(frozen=True)
class _Episodes:
    """Parses the forwarded `episodes=` value (typed like bench run's)."""

    episodes: int = 1


def episodes_of(user_keys: Mapping[str, str], default: int) -> int:
    """The forwarded `episodes=` value, typed like bench run's, or `default` when none was given."""
    return int(config_mod.build(_Episodes, [user_keys["episodes"]]).episodes) if "episodes" in user_keys else default


def override(key: str, value: Any) -> str:
    """`key=value` as a run's override (JSON is valid YAML flow, which the override grammar parses)."""
    return f"{key}={json.dumps(value)}"


def recorded_settings(
    sides: Sequence[Side], user_keys: Mapping[str, str], default: Callable[[], int]
) -> tuple[Side | None, list[str], int]:
    """Load the recorded sides' episodes; return the first recorded side, the settings both sides must share (its
    run's `SHARED_KEYS`, as overrides) and the episodes per cell: `episodes=` if given (at most the recorded run's),
    else the recorded run's, else `default()`. ConfigError for more episodes than the recorded run has, or < 1."""
    recorded = [s for s in sides if s.info["kind"] == "run"]
    for side in recorded:
        side.records, side.meta = load_recorded(side.info["run_dir"], side.role)
    ref = recorded[0] if recorded else None
    shared: list[str] = []
    if ref is not None:
        rc = ref.meta["config"]
        shared = [override(k, rc[k]) for k in SHARED_KEYS if rc.get(k) is not None]
        max_eps = int(rc.get("episodes", 0)) or max(r.episode for r in ref.records) + 1
        episodes = episodes_of(user_keys, max_eps)
        if episodes > max_eps:
            raise ConfigError(
                f"episodes={episodes}: the recorded {ref.role} run {ref.info['run_dir']} has only {max_eps} per cell"
            )
    else:
        episodes = episodes_of(user_keys, 0) if "episodes" in user_keys else default()
    if episodes < 1:
        raise ConfigError(f"episodes={episodes}: must be >= 1")
    return ref, shared, episodes


# -- running -----------------------------------------------------------------------------------
class Side:
    """One side of the comparison: a live run (planned by `bench.api.plan`) or recorded episodes."""

    def __init__(self, role: str, info: dict[str, Any]):
        self.role, self.info = role, info
        self.p: Plan | None = None  # the plan of a live side
        self.meta: dict[str, Any] = {}  # run metadata: loaded for a recorded side, from start() for a live one
        self.records: list[EpisodeRecord] = []
        self.wanted: set[str] = set()  # job ids a live side runs (those the recorded side has)

    @property
    def live(self) -> bool:
        return self.p is not None

    def describe(self) -> dict[str, Any]:
        meta = self.meta or {}
        pol = meta.get("policy", {})
        run_dir = self.p.run_dir if self.p is not None else self.info.get("run_dir")
        return {
            "spec": self.info["spec"],
            "kind": self.info["kind"],
            "policy": pol.get("name"),
            "checkpoint": pol.get("checkpoint"),
            "checkpoint_sha256": pol.get("checkpoint_sha256"),
            "run_id": meta.get("run_id"),
            "run_dir": str(run_dir) if run_dir else None,
            "reused": not self.live,
        }


def prepare_live(side: Side, shared: list[str], forwarded: list[str], run_id: str, parent: Path) -> None:
    given = {config_mod.top_key(f) for f in forwarded}  # a key the user gave wins; the settings check names it
    argv = [
        *(o for o in shared if config_mod.top_key(o) not in given),
        *forwarded,
        f"policy={side.info['policy']}",
        f"out={parent}",
        f"run_id={run_id}",
    ]
    if side.info.get("checkpoint"):
        argv.append(f"checkpoint={side.info['checkpoint']}")
    side.p = plan(parse_run(argv))  # parsed once, planned once


def live_plan(side: Side) -> Plan:
    assert side.p is not None, f"the {side.role} side is live"
    return side.p


def run_look(side: Side, n_episodes: int, workers: int) -> None:
    wanted = side.wanted
    result = run(
        live_plan(side),
        only=lambda j: j.episode < n_episodes and j.job_id in wanted,
        summarize=False,
        executor=LocalExecutor(workers),
    )
    side.records = result.records


def check_same_settings(
    cand_cfg: dict[str, Any], base_config: dict[str, Any], user_keys: dict[str, str], base_dir: Path
) -> None:
    mine = {k: cand_cfg.get(k) for k in SHARED_KEYS}
    for k in (k for k in SHARED_KEYS if k in base_config):  # keys an older run.json lacks are not compared
        if mine.get(k) != base_config.get(k):
            given = f" (you gave {user_keys[k]})" if k in user_keys else ""
            raise ConfigError(
                f"{k}={mine.get(k)!r} differs from the baseline run {base_dir} ({k}="
                f"{base_config.get(k)!r}){given}: paired episodes need the same settings"
            )


# -- checks before anything runs -----------------------------------------------------------------
def check_sides_pairable(ref: Side, others: list[Side]) -> None:
    """The recorded `ref` run holds the cells and seeds the other side plays (else ConfigError naming it)."""
    for side in others:
        cells = cells_of_jobs(live_plan(side).jobs) if side.live else cells_of_records(side.records)
        seeds = (
            {j.job_id: j.seed for j in live_plan(side).jobs} if side.live else {r.job_id: r.seed for r in side.records}
        )
        check_pairable(ref.records, f"the {ref.role} run {ref.info['run_dir']}", side.role, cells, seeds, side.live)


def input_paths(sides: list[Side]) -> list[tuple[Path, str]]:
    """Files and folders the gate reads, which no output may overwrite or lie inside."""
    inputs: list[tuple[Path, str]] = []
    for side in sides:
        if side.info["kind"] == "run":
            inputs.append((Path(side.info["run_dir"]).resolve(), f"the {side.role} run directory"))
        elif side.info.get("checkpoint"):
            ck = Path(side.info["checkpoint"]).resolve()
            inputs += [(ck, f"the {side.role} checkpoint"), (ck.with_suffix(".json"), f"the {side.role} spec")]
    return inputs


def checkpoint_of(side: Side) -> tuple[str | None, str | None]:
    """(checkpoint path, sha256) of a side's policy: from the live plan, or as its run recorded it."""
    if side.p is not None:
        return portable(side.p.identity.checkpoint), side.p.identity.checkpoint_sha256
    pol = (side.meta or {}).get("policy", {})
    return pol.get("checkpoint"), pol.get("checkpoint_sha256")


def describe_side(side: Side, provenance: dict[str, Any] | None) -> dict[str, Any]:
    d = side.describe()
    if d["policy"] is None:
        d["policy"] = side.p.config.policy if side.p is not None else side.info.get("policy")
    path, sha = checkpoint_of(side)
    d["checkpoint"], d["checkpoint_sha256"] = d["checkpoint"] or path, d["checkpoint_sha256"] or sha
    return {**d, "provenance": provenance}


def side_provenance(side: Side) -> dict[str, Any] | None:
    path, sha = checkpoint_of(side)
    if not path:
        return None
    return checkpoint_provenance(path, sha, hash_file=not side.live)  # a live side's plan has just hashed it
