"""What the data identify: parameters alone, combinations of them, and what they leave open.

The fit's weighted training regressor A (each joint's equations divided by its residual spread) has
columns scaled to each parameter's *plausible size* s (a link's prior scale; for a joint term, the
value that moves that joint's torque by a tenth of its spread). Its Fisher information
F = (A S)' (A S) / (sigma^2 tau) (sigma^2: the weighted residual variance, tau: the residuals'
autocorrelation time, as the fit's covariance) is decomposed: a direction with information below
1 / IDENT_SD^2 is one the data pin to no better than half its plausible size, and is **not
identified**. The data alone give no interval along those directions: a parameter with a share of
them has an unbounded interval (as a covariance from the data alone, not from the faint pull toward
declared values that keeps the fit there), and is

- `identified`: under 1% of it lies in unidentified directions (its interval is finite);
- `in combination`: partly: the combination of parameters the data do identify is named, with its
  value and interval (e.g. "payload.mx + 0.42 payload.mass", a first moment about a point);
- `not identifiable`: over 99%: the data say nothing of it; it stays where the declared value and the
  physics (a link must be a body) put it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TypedDict

import numpy as np

from bench.calibrate.arm.idim import Block, design

IDENT_SD = 0.5  # a direction is identified when the data alone pin it to half its plausible size (1 sd)
SHARE_ALONE, SHARE_NONE = 0.01, 0.99  # shares of unidentified directions: identified alone / not at all
TERM_MIN = 0.1  # terms of a combination smaller than this (relative, in plausible sizes) are left out


def unit_of(label: str) -> str:
    """The physical unit of a parameter, from its label's last part."""
    last = label.rsplit(".", 1)[-1]
    return {
        "mass": "kg",
        "mx": "kg·m",
        "my": "kg·m",
        "mz": "kg·m",
        "coulomb": "N·m",
        "offset": "N·m",
        "viscous": "N·m·s/rad",
        "armature": "kg·m²",
        "stiffness": "N·m/rad",
        "gain_error": "",
        "stribeck_excess": "N·m",
        "asymmetry": "N·m",
    }.get(last, "kg·m²" if last.startswith("i") else "")


def plausible_sizes(blocks: list[Block], rows: np.ndarray, spread: np.ndarray) -> np.ndarray:
    """(K,) each parameter's plausible size: a block's prior scale where it has one, else the value that
    moves the joint it acts on most by a tenth of that joint's torque spread."""
    out = []
    for b in blocks:
        cols = b.cols[rows]  # (N, n, k)
        rms = np.sqrt(np.mean(cols**2, axis=0))  # (n, k)
        for i in range(b.size):
            if np.isfinite(b.scale[i]):
                out.append(float(b.scale[i]))
                continue
            j = int(np.argmax(rms[:, i]))
            out.append(0.1 * float(spread[j]) / max(float(rms[j, i]), 1e-12))
    return np.asarray(out)


# what the data say of one parameter: "identified", "not identifiable" (with its unidentified share) or "in
# combination" (with the parameters it is tied to, its unidentified share and the combination in words)
Status = TypedDict(
    "Status", {"status": str, "with": list[str], "unidentified_share": float, "combination": str}, total=False
)


class Combination(TypedDict):
    """A combination of parameters the data identify where its parameters are not identified alone."""

    combination: str  # in words, the first parameter's coefficient 1
    terms: dict[str, float]  # parameter -> coefficient (physical units)
    value: float
    unit: str
    interval: list[float]  # 95%
    parameters: list[str]  # those not identified alone that it ties


@dataclass
class Identifiability:
    """Per parameter, whether the data identify it, its data-only standard deviation, and the combinations."""

    labels: list[str]
    status: dict[str, Status]  # label -> what the data say of it
    sd: np.ndarray  # (K,) data-only standard deviation; inf where a share is unidentified
    combinations: list[Combination] = field(default_factory=list)
    information: list[float] = field(default_factory=list)  # eigenvalues of F, ascending
    unidentified: int = 0  # directions the data do not identify

    def to_json(self) -> dict[str, object]:
        return {
            "method": (
                "eigen-directions of the Fisher information of the weighted training regressor (parameters "
                f"in their plausible sizes); a direction is identified when the data alone pin it within "
                f"{IDENT_SD:g} of its plausible size (one standard deviation)"
            ),
            "parameters": len(self.labels),
            "identified_directions": len(self.labels) - self.unidentified,
            "unidentified_directions": self.unidentified,
            "condition_number": (
                float(self.information[-1] / self.information[0])
                if self.information and self.information[0] > 0
                else None
            ),
            "combinations": self.combinations,
        }


def analyse(
    blocks: list[Block],
    x: np.ndarray,
    rows: np.ndarray,
    weights: np.ndarray,
    noise: float,
    spread: np.ndarray,
) -> Identifiability:
    """The analysis of the module docstring for a fit `x` on `blocks` over training `rows`.

    `noise` is sigma^2 tau of the weighted residuals (the fit's `tau * ssr / dof`).
    """
    labels = [lab for b in blocks for lab in b.labels]
    size = plausible_sizes(blocks, rows, spread)
    a = (design(blocks, rows) * weights[None, :, None]).reshape(-1, len(labels)) * size[None, :]
    info = (a.T @ a) / max(noise, 1e-300)
    lam, vec = np.linalg.eigh(info)
    ident = lam >= 1.0 / IDENT_SD**2
    v_id, v_un = vec[:, ident], vec[:, ~ident]
    share = np.sum(v_un**2, axis=1) if v_un.size else np.zeros(len(labels))
    cov_n = (v_id / lam[ident]) @ v_id.T  # data-only covariance along identified directions (plausible sizes)
    sd = np.sqrt(np.maximum(np.diag(cov_n), 0.0)) * size
    sd = np.where(share < SHARE_ALONE, sd, np.inf)
    status: dict[str, Status] = {}
    combos: dict[tuple[str, ...], Combination] = {}
    for k, lab in enumerate(labels):
        if share[k] < SHARE_ALONE:
            status[lab] = {"status": "identified"}
            continue
        if share[k] > SHARE_NONE:
            status[lab] = {"status": "not identifiable", "unidentified_share": round(float(share[k]), 3)}
            continue
        c = v_id @ v_id[k]  # the identified combination nearest to this parameter alone (plausible sizes)
        keep = np.flatnonzero(np.abs(c) >= TERM_MIN * abs(c[k]))
        coef = (c[keep] / c[k]) * (size[k] / size[keep])  # physical units, this parameter's coefficient 1
        w = np.zeros(len(labels))
        w[keep] = coef
        value = float(w @ x)
        var = float((w * size) @ cov_n @ (w * size))  # of w'x, with cov_n in plausible sizes
        key = tuple(sorted(labels[j] for j in keep))
        terms = [(k, 1.0)] + sorted(
            ((j, cf) for j, cf in zip(keep.tolist(), coef.tolist()) if j != k), key=lambda t: -abs(t[1]) * size[t[0]]
        )
        text = _combination_text([(labels[j], cf) for j, cf in terms])
        half = 1.96 * np.sqrt(max(var, 0.0))
        entry = combos.setdefault(
            key,
            {
                "combination": text,
                "terms": {labels[j]: cf for j, cf in zip(keep.tolist(), coef.tolist())},
                "value": value,
                "unit": unit_of(lab),
                "interval": [value - half, value + half],
                "parameters": [],
            },
        )
        entry["parameters"].append(lab)
        partners = [labels[j] for j, _ in terms if j != k][:3]
        status[lab] = {
            "status": "in combination",
            "with": partners,
            "unidentified_share": round(float(share[k]), 3),
            "combination": entry["combination"],
        }
    return Identifiability(labels, status, sd, list(combos.values()), lam.tolist(), int((~ident).sum()))


TEXT_TERMS = 4  # terms of a combination written out in words (all are in its `terms`)


def _combination_text(terms: list[tuple[str, float]]) -> str:
    """'a + 0.42 b - c' from (label, coefficient) pairs, the first with coefficient 1, largest first."""
    out = terms[0][0]
    for lab, cf in terms[1:TEXT_TERMS]:
        mag = "" if abs(abs(cf) - 1.0) < 1e-3 else f"{abs(cf):.3g} "
        out += f" {'-' if cf < 0 else '+'} {mag}{lab}"
    if len(terms) > TEXT_TERMS:
        out += f" + {len(terms) - TEXT_TERMS} smaller term(s)"
    return out


def payload_sentence(ident: Identifiability, prefix: str) -> str | None:
    """In words, what a payload's block identifies when its mass is not identified alone (None when it is)."""
    mass = f"{prefix}.mass"
    st = ident.status.get(mass)
    if st is None or st["status"] == "identified":
        return None
    moments = [ax for ax in ("mx", "my", "mz") if ident.status.get(f"{prefix}.{ax}", {}).get("status") == "identified"]
    parts = []
    if moments:
        parts.append(
            "only its first moment (mass x centre of mass) along "
            + ", ".join(ax[1] for ax in moments)
            + " is identified alone"
        )
    combo = next((c for c in ident.combinations if mass in c["parameters"]), None)
    if combo is not None:
        lo, hi = combo["interval"]
        parts.append(
            f"the data identify {combo['combination']} = {combo['value']:.4g} [{lo:.4g}, {hi:.4g}] {combo['unit']}"
        )
    why = "; ".join(parts) if parts else "the data say nothing of it"
    return (
        f"the payload's mass and centre of mass are not identified apart ({why}): mass and centre-of-mass "
        "intervals are unbounded along that trade-off; record an excitation that moves the flange in several "
        "directions (bench calibrate design)"
    )
