"""A look of `bench compare`: the paired tests pooled and per cell, and the answer; the unpaired comparison.

Paired (common seeds): the pooled test uses the design's alpha and beta (it decides when to stop); each
cell's test uses alpha / C and beta / C (C cells: Bonferroni), so the chance that any cell's claim is
wrong is at most alpha (a direction) or beta (an equivalence) too. A cell keeps the first answer it
reaches; the comparison stops when the pooled answer is reached (every answer is valid at whatever look
the comparison stops: the boundaries hold over all looks). The interval printed with each difference is
the repeated confidence interval of that look (Tango's score interval at the one-sided level Phi(c_k),
Jennison & Turnbull 1989): it covers d at every look at once with probability >= 1 - alpha.

Unpaired (two recorded runs on other seeds, `paired=false`): one look. A direction is named when
Boschloo's exact two-sided p-value is below alpha (alpha / C per cell), Fisher's printed beside it;
equivalence when Newcombe's interval for d at confidence 1 - 2 beta (two one-sided tests at beta) lies
within (-delta, delta).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from bench.board.compare.design import Design, answer, statistics
from bench.board.gate.sequential import CellKey, Pairs, cell_id
from bench.scoring import exact
from bench.scoring import stats as scoring

ANSWERS = ("a_better", "b_better", "equivalent")
WORDS = {
    "a_better": "A BETTER",
    "b_better": "B BETTER",
    "equivalent": "EQUIVALENT",
    "inconclusive": "INCONCLUSIVE",
    "continue": "continue",
    "nothing_measured": "NOTHING MEASURED",
}
Z_CAP = 8.0  # an interval at a look whose boundary is beyond this is shown at this level (Phi(8) = 1 - 6e-16)


def _rci(g: Pairs, c: float) -> tuple[float, float]:
    """The repeated confidence interval for d = p10 - p01 at a look whose boundary is c."""
    from scipy.special import ndtr  # scipy: loaded only when a comparison is scored

    level = float(ndtr(min(c, Z_CAP)))
    return (
        scoring.paired_score_bound(g.n10, g.n01, g.n, level, "lower"),
        scoring.paired_score_bound(g.n10, g.n01, g.n, level, "upper"),
    )


def paired_test(test_id: str, g: Pairs, design: Design, look: int, bounds: bool = True) -> dict[str, Any]:
    """One paired test at `look`: rates, d, its statistics against the look's boundaries, interval, answer
    (`bounds=False`: no interval, for simulations; the answer does not use it)."""
    c, e = design.efficacy[look], design.equivalence[look]
    za, zb, zu, zl = (float(z) for z in statistics(g.n10, g.n01, g.n, design.delta))
    lo, hi = _rci(g, c) if bounds else (-1.0, 1.0)
    return {
        "id": test_id,
        "pairs": g.n,
        "a": round((g.n11 + g.n10) / g.n, 6),
        "b": round((g.n11 + g.n01) / g.n, 6),
        "a_only": g.n10,
        "b_only": g.n01,
        "diff": round(g.drop, 6),
        "lo": round(lo, 6),
        "hi": round(hi, 6),
        "z_a": finite(za),
        "z_b": finite(zb),
        "z_upper": finite(zu),
        "z_lower": finite(zl),
        "bound": finite(c),
        "equivalence_bound": finite(e),
        "alpha": float(f"{design.alpha:.6g}"),
        "beta": float(f"{design.beta:.6g}"),
        "answer": answer(za, zb, zu, zl, c, e),
    }


def finite(x: float) -> float | None:
    return round(x, 6) if math.isfinite(x) else None  # JSON has no inf


def evaluate_look(
    cells: Mapping[CellKey, Pairs], design: Design, look: int, n_cells: int, bounds: bool = True
) -> dict[str, Any]:
    """The pooled test (the answer) and, with >= 2 cells, each cell's at `look` (0-based).

    Args:
        cells: paired counts per cell (cells without pairs are left out).
        n_cells: the planned cells (each cell's test gets alpha / n_cells, beta / n_cells).
        bounds: also the repeated confidence intervals (reporting only; simulations skip them).
    """
    cells = {k: v for k, v in cells.items() if v.n > 0}
    if not cells:
        return {"pairs": 0, "answer": "continue", "reason": "no paired episodes without errors"}
    keys = sorted(cells)
    pooled = sum((cells[k] for k in keys), Pairs())
    tests = [paired_test("pooled", pooled, design, look, bounds)]
    if n_cells >= 2:
        per_cell = design.scaled(1.0 / n_cells)
        tests += [paired_test(cell_id(k), cells[k], per_cell, look, bounds) for k in keys]
    return {"pairs": pooled.n, "tests": tests, "answer": tests[0]["answer"]}


def cell_answers(looks: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Each test's first answer over the looks taken (a claim once made stands), else its last look's row."""
    out: dict[str, dict[str, Any]] = {}
    for i, look in enumerate(looks):
        for t in look.get("tests", []):
            if t["id"] in out and out[t["id"]]["answer"] in ANSWERS:
                continue
            out[t["id"]] = {**t, "look": i + 1}
    return out


def verdict_of(looks: list[dict[str, Any]]) -> str:
    """The comparison's answer: the last look's pooled answer, "inconclusive" when it is still "continue"."""
    last = looks[-1]["answer"] if looks else "continue"
    return last if last in ANSWERS else "inconclusive"


def rule(design: Design, n_cells: int) -> str:
    """The decision rule in words, for the comparison document."""
    return (
        f"paired by seed, d = success(A) - success(B); at each of {len(design.schedule)} look(s) A (B) is better if "
        f"the exact McNemar (sign) test of d = 0, as a z, is >= c_k, boundaries spending alpha {design.alpha}/2 per direction "
        f"(Lan-DeMets O'Brien-Fleming); equivalent within delta {design.delta} if Tango's score tests reject "
        f"d >= delta and d <= -delta at boundaries spending beta {design.beta}; pooled over all pairs (decides "
        f"when to stop) and per cell ({n_cells} cells, alpha and beta / {n_cells} each); inconclusive at the cap"
    )


# -- unpaired --------------------------------------------------------------------------------------
def unpaired_test(
    test_id: str, a: np.ndarray, b: np.ndarray, alpha: float, beta: float, delta: float
) -> dict[str, Any]:
    """Two unpaired batches of 0/1 outcomes: Boschloo's exact test (Fisher's beside), Newcombe's interval, answer."""
    xa, na, xb, nb = int(np.sum(a)), len(a), int(np.sum(b)), len(b)
    p = exact.boschloo(xa, na, xb, nb)
    diff = xa / na - xb / nb
    cis = scoring.mover(scoring.wilson(xa, na, 1 - 2 * beta), scoring.wilson(xb, nb, 1 - 2 * beta))
    lo, hi = float(cis.lo if cis.lo is not None else -1.0), float(cis.hi if cis.hi is not None else 1.0)
    if p < alpha:
        ans = "a_better" if diff > 0 else "b_better"
    elif -delta < lo and hi < delta:
        ans = "equivalent"
    else:
        ans = "inconclusive"
    return {
        "id": test_id,
        "a_episodes": na,
        "b_episodes": nb,
        "a": round(xa / na, 6),
        "b": round(xb / nb, 6),
        "diff": round(diff, 6),
        "lo": round(lo, 6),
        "hi": round(hi, 6),
        "level": round(1 - 2 * beta, 6),
        "boschloo_p": float(f"{p:.6g}"),
        "fisher_p": float(f"{exact.fisher(xa, na, xb, nb):.6g}"),
        "alpha": float(f"{alpha:.6g}"),
        "answer": ans,
    }


def unpaired(
    a_cells: Mapping[CellKey, np.ndarray],
    b_cells: Mapping[CellKey, np.ndarray],
    alpha: float,
    beta: float,
    delta: float,
) -> list[dict[str, Any]]:
    """The pooled unpaired test (all episodes of each side) and, with >= 2 cells, each cell's at alpha / C, beta / C."""
    keys = sorted(set(a_cells) & set(b_cells))
    pooled_a = np.concatenate([a_cells[k] for k in keys])
    pooled_b = np.concatenate([b_cells[k] for k in keys])
    tests = [unpaired_test("pooled", pooled_a, pooled_b, alpha, beta, delta)]
    if len(keys) >= 2:
        share = 1.0 / len(keys)
        tests += [unpaired_test(cell_id(k), a_cells[k], b_cells[k], alpha * share, beta * share, delta) for k in keys]
    return tests
