"""The entries of an arm calibration's result: each fitted parameter with its interval and status, each link's
mass and centre of mass, found effects in their own units, and the warnings a user must not miss.

What `bench.calibrate.arm.loop.calibrate_arm` writes into calibration.json from its fits (`bench.calibrate.arm.idim`)
and what the data identify (`bench.calibrate.arm.identifiability`): a parameter the data do not identify alone
has no interval (`null`, unbounded), never a narrow one that the faint pull toward its declared value made.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from bench.calibrate.arm.identifiability import Identifiability, Status
from bench.calibrate.arm.idim import Fit, bounds_of
from bench.calibrate.arm.inertial import feasible
from bench.calibrate.arm.model import ArmModel, Values, group_std
from bench.calibrate.arm.spec import ArmSpec

UNBOUNDED = "unbounded: the data do not identify it alone (see identifiability.combinations)"


def effect_terms(entry: Mapping[str, object], f: Fit, draws: np.ndarray, ident: Identifiability) -> dict[str, object]:
    """A found effect in its own terms: a payload's mass and centre of mass (m, in the payload frame),
    a drive's gain; 95% intervals from the draws (percentiles) or, without, the delta method; none where
    the data do not identify the quantity alone."""
    if entry["name"] == "payload":
        off = f.offset("payload")
        labels = f.labels[off : off + 4]
        x, cov = f.x[off : off + 4], f.cov[off : off + 4, off : off + 4]
        d = draws[:, off : off + 4] if len(draws) >= 20 else None
        com = x[1:] / x[0]
        out: dict[str, object] = {"mass": float(x[0]), "com": com.tolist()}
        alone = [ident.status.get(lab, {}).get("status") == "identified" for lab in labels]
        if not alone[0]:
            out["mass_interval"] = None
            out["com_interval"] = None
            out["interval_note"] = UNBOUNDED
            return out
        jac = np.hstack([-com[:, None] / x[0], np.eye(3) / x[0]])
        sd_com = np.sqrt(np.maximum(np.diag(jac @ cov @ jac.T), 0.0))
        sd_m = float(np.sqrt(max(cov[0, 0], 0.0)))
        if d is not None:
            dc = d[:, 1:] / np.maximum(d[:, :1], 1e-12)
            lo, hi = np.percentile(d[:, 0], [2.5, 97.5])
            out["mass_interval"] = [float(min(lo, x[0] - 1.96 * sd_m)), float(max(hi, x[0] + 1.96 * sd_m))]
            clo, chi = np.percentile(dc, [2.5, 97.5], axis=0)
            out["com_interval"] = [
                [float(min(a, c - 1.96 * s)), float(max(b, c + 1.96 * s))] if ok else None
                for a, b, c, s, ok in zip(clo, chi, com, sd_com, alone[1:])
            ]
        else:
            out["mass_interval"] = [float(x[0] - 1.96 * sd_m), float(x[0] + 1.96 * sd_m)]
            out["com_interval"] = [
                [float(c - 1.96 * s), float(c + 1.96 * s)] if ok else None for c, s, ok in zip(com, sd_com, alone[1:])
            ]
        return out
    if entry["name"] == "actuator_gain":
        off = f.offset(f"gain:{entry['target']}")
        sd = float(np.sqrt(max(f.cov[off, off], 0.0)))
        return {
            "gain": float(1.0 + f.x[off]),
            "gain_interval": [float(1 + f.x[off] - 1.96 * sd), float(1 + f.x[off] + 1.96 * sd)],
        }
    return {}


def param_entries(final: Fit, declared: Fit, ident: Identifiability, draws: np.ndarray, spec: ArmSpec) -> list[dict]:
    """Each fitted parameter: its value, the declared one, whether the data identify it, a 95% interval (the data's
    alone: unbounded, null, where they do not identify it), clipped to the parameter's physical bounds."""
    prior = np.concatenate([b.prior for b in final.blocks])
    lo, hi = bounds_of(final.blocks)
    out = []
    for i, lab in enumerate(final.labels):
        st = dict(ident.status.get(lab, {"status": "identified"}))
        entry: dict[str, object] = {"name": lab, "value": float(final.x[i]), "declared": float(prior[i]), **st}
        moved = abs(final.x[i] - prior[i]) > 0.01 * max(abs(prior[i]), 1e-9) + 1e-9
        if st["status"] != "identified":
            entry["interval"] = None
            entry["interval_method"] = UNBOUNDED
            if st["status"] == "not identifiable":
                entry["moved"] = bool(moved)
                entry["why"] = (
                    "the data say nothing of it; it moved with the parameters it is tied to (a link must stay a "
                    "physical body, within its plausibility fence)"
                    if moved
                    else "the data say nothing of it: left at its declared value"
                )
            if lab in final.at_bound:
                entry["at_bound"] = True
            out.append(entry)
            continue
        # identified: the wider of a window bootstrap and the data-only covariance, within the physical bounds
        bounds, how = [], []
        if len(draws) >= 20:
            bounds.append(np.percentile(draws[:, i], [2.5, 97.5]))
            how.append(f"window bootstrap ({len(draws)} draws)")
        sd = float(ident.sd[i])
        if np.isfinite(sd) and sd > 0:
            bounds.append(np.array([final.x[i] - 1.96 * sd, final.x[i] + 1.96 * sd]))
            how.append("the data's own covariance x autocorrelation time")
        if bounds:
            a, b = float(min(v[0] for v in bounds)), float(max(v[1] for v in bounds))
            a, b = max(a, float(lo[i])), min(b, float(hi[i]))
            entry["interval"] = [a, b]
            entry["interval_method"] = "the wider of " + " and ".join(how) if len(how) > 1 else how[0]
            entry["excludes_zero"] = bool(a > 0 or b < 0)
            if not entry["excludes_zero"]:
                entry["status"] = "identified, consistent with zero"
        if lab in final.at_bound:
            entry["at_bound"] = True
        out.append(entry)
    return out


def link_entries(am: ArmModel, values: Values, ident: Mapping[str, Status]) -> list[dict]:
    """Each link's declared and fitted mass and centre of mass, and whether the fitted link is a physical body."""
    out = []
    for name, group in zip(am.links, am.groups):
        p0 = group_std(am.model, group)
        p = np.asarray(values["links"].get(name, p0))
        mass = float(p[0])
        out.append(
            {
                "link": name,
                "declared_mass": float(p0[0]),
                "mass": mass,
                "declared_com": (p0[1:4] / p0[0]).tolist() if p0[0] > 0 else None,
                "com": (p[1:4] / mass).tolist() if mass > 0 else None,
                "mass_status": ident.get(f"{name}.mass", {"status": "declared (not fitted)"})["status"],
                "physical": feasible(p) is None,
            }
        )
    return out


def warnings_of(final: Fit, params: list[dict], errors: dict[str, Any], am: ArmModel) -> list[str]:
    """What a user must not miss: bounds reached, parameters the data leave open, errors that rose."""
    out = []
    at = [p["name"] for p in params if p.get("at_bound")]
    if at:
        out.append(f"{len(at)} parameter(s) ended at a bound: {', '.join(at)} (the bound, not the data, set them)")
    none = [p for p in params if p["status"] == "not identifiable"]
    combo = [p for p in params if p["status"] == "in combination"]
    if none or combo:
        moved = [p["name"] for p in none if p.get("moved")]
        out.append(
            f"{len(none)} parameter(s) not identifiable from these logs ({len(none) - len(moved)} left at their declared "
            f"values, {len(moved)} moved with the parameters they are tied to: {', '.join(moved) or 'none'}); "
            f"{len(combo)} identified only in combination (calibration.json identifiability.combinations): their "
            "intervals are unbounded"
        )
    tq = errors["torque"]
    rose = [am.joints[i] for i, (a, b) in enumerate(zip(tq["nominal"]["rmse"], tq["final"]["rmse"])) if b > a * 1.001]
    if rose:
        out.append(f"held-out torque error rose on {', '.join(rose)} (nominal -> final)")
    return out


def uncarried_effects(values: Values, added: list[dict], spec: ArmSpec) -> list[str]:
    """What the fit found that the calibrated MuJoCo model cannot carry (reported only)."""
    out = []
    if "offset" in spec.friction:
        out.append("offset: a constant in the torque signal (a sensor or command offset), not a force on the arm")
    for a in added:
        if a["name"] in ("stribeck_friction", "asymmetric_friction"):
            out.append(f"{a['name']} at {a['target']}: no MuJoCo field carries it (reported only)")
    return out
