"""A checkpoint sweep on the report page (`bench report SWEEP_DIR|sweep.json out=DIR`): the curve of success against
training step (`figures.fig_sweep`), the per-checkpoint table with the best set and the selection, and the sweep's
leaderboard (its per-checkpoint entries) when it lies beside the sweep document."""

from __future__ import annotations

from pathlib import Path

from bench.board.report.figures import fig_sweep
from bench.board.report.html import esc, img_tag, rate_cell, table_html
from bench.core.errors import DataError
from bench.core.schema import load_json, validate

SWEEP_ID = "bench.sweep/1"


def load_sweep(path: Path) -> tuple[dict, dict | None]:
    """The sweep document (validated against bench.sweep/1) and the leaderboard beside it (validated), if any.

    Raises:
        DataError: not a sweep document, a field the schema refuses, a selected or best-set checkpoint the
            sweep does not hold, or a broken leaderboard.json beside it.
    """
    doc = load_json(path)
    sid = validate(doc, str(path))
    if sid != SWEEP_ID:
        raise DataError(f"{path}: schema {sid} is not a checkpoint sweep ({SWEEP_ID})")
    names = [c["name"] for c in doc["checkpoints"]]
    for field, named in (
        ("selected", [doc["selected"]] if doc["selected"] is not None else []),
        ("best_set", doc["best_set"]),
    ):
        missing = [n for n in named if n not in names]
        if missing:
            raise DataError(f"{path}: field {field} names {missing[0]!r}, not one of the sweep's checkpoints {names}")
    board_path = path.parent / "leaderboard.json"
    board = None
    if board_path.is_file():
        board = load_json(board_path)
        if validate(board, str(board_path)) != "bench.leaderboard/1":
            raise DataError(
                f"{board_path}: beside a sweep, leaderboard.json must be a leaderboard (bench.leaderboard/1)"
            )
    return doc, board


def sweep_sections(doc: dict, tmp: Path) -> list[str]:
    """The sweep's curve and its per-checkpoint table."""
    parts = ["<h2>Checkpoint sweep</h2>"]
    if fig_sweep(doc, tmp / "sweep.png"):
        parts.append(img_tag("sweep.png", "success against training step"))
    conf = f"{doc['simultaneous_confidence']:.3g}"
    rows = []
    for c in doc["checkpoints"]:
        beaten = c["beaten_by"]
        best = "yes" + (" (selected)" if c["name"] == doc["selected"] else "") if c["in_best_set"] else "no"
        rows.append(
            [
                esc(c["name"]),
                f"{c['step']:g}",
                str(c["episodes"]),
                rate_cell(c["success"]),
                best,
                "–" if beaten is None else f"{esc(beaten['checkpoint'])} (lower bound {beaten['lower_bound']:+.3f})",
            ]
        )
    selected = doc["selected"]
    parts.append(
        f"<p class='note'>{esc(doc['metric'])} per checkpoint with {conf} simultaneous intervals; steps from "
        f"{esc(doc['step_source'])}. Selected: <b>{esc(selected) if selected else 'none'}</b>. Method: "
        f"{esc(doc['method'])}.</p>"
        + table_html(["checkpoint", "step", "episodes", "success", "best set", "beaten by"], rows, {1, 2})
    )
    return parts
