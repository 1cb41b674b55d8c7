"""`bench regress paired=false`: the gate of two recorded runs whose episodes do not pair (other seeds).

Both sides must be recorded run directories of the same suite version, cells and metric; the episodes
each run has are compared cell by cell as two independent batches (`bench.board.gate.unpaired`: Chan's
exact unconditional test per cell, a stratified score test per split and pooled, weighted Holm, one look).
Everything is checked before a byte is written (one-line ConfigError, exit 2); the verdict JSON, JUnit
XML and Markdown are the paired gate's writers' (`bench.board.gate.outputs`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from bench.api.gate.sides import Side, describe_side, input_paths, side_provenance
from bench.board.gate import outputs, sequential
from bench.board.gate import unpaired as gate
from bench.board.gate.inputs import cells_of_records, check_outputs, load_recorded, require_binary
from bench.core.errors import ConfigError


def prepare(cand: Side, base: Side, forwarded: Sequence[str]) -> str:
    """Load and check both recorded runs (they may differ only in seeds and episodes); returns the metric."""
    if forwarded:
        key = forwarded[0].split("=", 1)[0]
        raise ConfigError(f"{key}=: paired=false compares two recorded runs as they are; it takes no bench run keys")
    for side in (cand, base):
        if side.info["kind"] != "run":
            raise ConfigError(
                f"{side.role}={side.info['spec']!r}: paired=false compares two recorded run directories "
                f"(this is a {side.info['kind']}; record it with bench run first)"
            )
        side.records, side.meta = load_recorded(side.info["run_dir"], side.role)
    cs, bs = cand.meta["suite"], base.meta["suite"]
    if (cs.get("name"), cs.get("version")) != (bs.get("name"), bs.get("version")):
        raise ConfigError(
            f"candidate run is suite {cs.get('name')} v{cs.get('version')}, baseline {bs.get('name')} "
            f"v{bs.get('version')}: the gate compares runs of one suite version"
        )
    mc = cand.meta["config"].get("metric", "success_once")
    mb = base.meta["config"].get("metric", "success_once")
    if mc != mb:
        raise ConfigError(f"candidate run scores metric {mc!r}, baseline {mb!r}: the gate compares one metric")
    metric = require_binary(mc)
    a, b = cells_of_records(cand.records), cells_of_records(base.records)
    if a != b:
        missing, extra = sorted(b - a), sorted(a - b)
        what = f"lacks cell {'/'.join(missing[0][:4])}" if missing else f"has cell {'/'.join(extra[0][:4])}"
        raise ConfigError(
            f"the candidate run {what} that the baseline {'has' if missing else 'does not have'} "
            f"({len(missing)} missing, {len(extra)} extra): the gate compares the same cells"
        )
    return metric


def run_unpaired(
    cfg: Any, cand: Side, base: Side, forwarded: Sequence[str], verdict_path: Path, schema: str, console: Any
) -> tuple[dict[str, Any], int, dict[str, Path]]:
    """Check, test and write the unpaired gate; returns (verdict document, exit code, paths written).

    `cfg` is the gate's `RegressConfig` (margin, alpha, cell_alpha, strict).
    """
    metric = prepare(cand, base, forwarded)
    paths = outputs.output_paths(verdict_path)
    check_outputs(paths, input_paths([cand, base]))
    cells, errors = gate.cell_batches(cand.records, base.records, metric)
    episodes = max(max(b.n_base, b.n_cand) for b in cells.values())
    console.print(
        f"regress (unpaired): candidate {cand.info['spec']} vs baseline {base.info['spec']}; {len(cells)} cells; "
        f"one look; alpha {cfg.alpha} ({cfg.cell_alpha:g} to the per-cell tests)"
    )
    look = gate.evaluate(cells, cfg.margin, cfg.alpha, cfg.cell_alpha, episodes)
    verdict, code = sequential.decide([look], cfg.strict)
    tests = {t["id"]: t for t in look.get("tests", [])}
    seeds = {s.role: int(s.meta["config"].get("seed", 0)) for s in (cand, base)}
    doc = {
        "schema": schema,
        "pairing": "unpaired",
        "test": gate.TEST_NAME,
        "pooled_test": gate.POOLED_NAME,
        "margin": cfg.margin,
        "alpha": cfg.alpha,
        "cell_alpha": cfg.cell_alpha,
        "metric": metric,
        "strict": cfg.strict,
        "suite": {"name": base.meta["suite"].get("name"), "version": base.meta["suite"].get("version")},
        "seed": seeds["candidate"],
        "seeds": seeds,
        "episodes_max": episodes,
        "schedule": [episodes],
        "rule": gate.rule(cfg.margin, cfg.alpha, cfg.cell_alpha, len(cells), metric),
        "verdict": verdict,
        "exit_code": code,
        "identical": False,
        "note": None,
        "stopped_early": False,
        "candidate": describe_side(cand, side_provenance(cand)),
        "baseline": describe_side(base, side_provenance(base)),
        "looks": [look],
        "cells": gate.cell_rows(cells, look),
        "splits": gate.split_rows(cells, look),
        "p_values": {t["id"]: t["p"] for t in look.get("tests", [])},
        "regressed": [sequential.regressed_entry(tests[h]) for h in look.get("regressed", [])],
        "errors": errors,
        "unpaired": 0,
        "wall_s": 0.0,
    }
    outputs.write(doc, paths, console)
    return doc, code, paths
