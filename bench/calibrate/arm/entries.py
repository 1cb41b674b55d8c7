"""The entries of an arm calibration's result: each fitted parameter with its interval and status, each link's
mass and centre of mass, found effects in their own units, and the warnings a user must not miss.

What `bench.calibrate.arm.loop.calibrate_arm` writes into calibration.json from its fits (`bench.calibrate.arm.idim`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from bench.calibrate.arm.idim import Fit
from bench.calibrate.arm.inertial import feasible
from bench.calibrate.arm.model import ArmModel, group_std
from bench.calibrate.arm.spec import ArmSpec


def effect_terms(entry: dict[str, Any], f: Fit, draws: np.ndarray) -> dict[str, Any]:
    """A found effect in its own terms: a payload's mass and centre of mass (m, in the payload frame),
    a drive's gain; 95% intervals from the draws (percentiles) or, without, the delta method."""
    if entry["name"] == "payload":
        off = f.offset("payload")
        x, cov = f.x[off : off + 4], f.cov[off : off + 4, off : off + 4]
        d = draws[:, off : off + 4] if len(draws) >= 20 else None
        com = x[1:] / x[0]
        jac = np.hstack([-com[:, None] / x[0], np.eye(3) / x[0]])
        sd_com = np.sqrt(np.maximum(np.diag(jac @ cov @ jac.T), 0.0))
        sd_m = float(np.sqrt(max(cov[0, 0], 0.0)))
        out: dict[str, Any] = {"mass": float(x[0]), "com": com.tolist()}
        if d is not None:
            dc = d[:, 1:] / np.maximum(d[:, :1], 1e-12)
            lo, hi = np.percentile(d[:, 0], [2.5, 97.5])
            out["mass_interval"] = [float(min(lo, x[0] - 1.96 * sd_m)), float(max(hi, x[0] + 1.96 * sd_m))]
            clo, chi = np.percentile(dc, [2.5, 97.5], axis=0)
            out["com_interval"] = [
                [float(min(a, c - 1.96 * s)), float(max(b, c + 1.96 * s))] for a, b, c, s in zip(clo, chi, com, sd_com)
            ]
        else:
            out["mass_interval"] = [float(x[0] - 1.96 * sd_m), float(x[0] + 1.96 * sd_m)]
            out["com_interval"] = [[float(c - 1.96 * s), float(c + 1.96 * s)] for c, s in zip(com, sd_com)]
        return out
    if entry["name"] == "actuator_gain":
        off = f.offset(f"gain:{entry['target']}")
        sd = float(np.sqrt(max(f.cov[off, off], 0.0)))
        return {
            "gain": float(1.0 + f.x[off]),
            "gain_interval": [float(1 + f.x[off] - 1.96 * sd), float(1 + f.x[off] + 1.96 * sd)],
        }
    return {}


def param_entries(final: Fit, declared: Fit, ident: dict[str, dict], draws: np.ndarray, spec: ArmSpec) -> list[dict]:
    """Each fitted parameter: its value, the declared one, whether the data identify it, a 95% interval."""
    sd = final.sd()
    prior = np.concatenate([b.prior for b in final.blocks])
    out = []
    for i, lab in enumerate(final.labels):
        entry: dict[str, Any] = {
            "name": lab,
            "value": float(final.x[i]),
            "declared": float(prior[i]),
            **ident.get(lab, {"status": "identified"}),
        }
        if entry["status"] == "not identifiable" and abs(final.x[i] - prior[i]) > 0.01 * max(abs(prior[i]), 1e-9):
            entry["why"] = "the data say nothing of it alone; the link's physical consistency moved it"
        # the wider of a window bootstrap and the covariance inflated by the residuals' autocorrelation
        # time: each alone can be too narrow for one correlated trajectory
        bounds, how = [], []
        if len(draws) >= 20:
            bounds.append(np.percentile(draws[:, i], [2.5, 97.5]))
            how.append(f"window bootstrap ({len(draws)} draws)")
        if sd[i] > 0:
            bounds.append(np.array([final.x[i] - 1.96 * sd[i], final.x[i] + 1.96 * sd[i]]))
            how.append("covariance x autocorrelation time")
        if bounds:
            entry["interval"] = [float(min(b[0] for b in bounds)), float(max(b[1] for b in bounds))]
            entry["interval_method"] = "the wider of " + " and ".join(how) if len(how) > 1 else how[0]
        if lab in final.at_bound:
            entry["at_bound"] = True
        out.append(entry)
    return out


def link_entries(am: ArmModel, values: dict[str, Any], ident: dict[str, dict]) -> list[dict]:
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
    none = [p["name"] for p in params if p["status"] == "not identifiable"]
    if none:
        out.append(f"{len(none)} parameter(s) not identifiable from these logs, left at their declared values")
    tq = errors["torque"]
    rose = [am.joints[i] for i, (a, b) in enumerate(zip(tq["nominal"]["rmse"], tq["final"]["rmse"])) if b > a * 1.001]
    if rose:
        out.append(f"held-out torque error rose on {', '.join(rose)} (nominal -> final)")
    fw = errors.get("forward", {})
    if "k_step" in fw:
        k0, k1 = fw["k_step"]["nominal"]["rmse"], fw["k_step"]["final"]["rmse"]
        rose = [am.joints[i] for i, (a, b) in enumerate(zip(k0, k1)) if b > a * 1.001]
        if rose:
            out.append(f"forward k-step position error rose on {', '.join(rose)} while the torque fit improved")
        if fw["k_step"]["final"]["nrmse"] > fw["k_step"]["nominal"]["nrmse"] * 1.001:
            out.append(
                f"forward k-step NRMSE rose overall ({fw['k_step']['nominal']['nrmse']:.4g} -> "
                f"{fw['k_step']['final']['nrmse']:.4g}): the fitted torque model does not simulate better"
            )
    return out


def uncarried_effects(values: dict[str, Any], added: list[dict], spec: ArmSpec) -> list[str]:
    """What the fit found that the calibrated MuJoCo model cannot carry (reported only)."""
    out = []
    if "offset" in spec.friction:
        out.append("offset: a constant in the torque signal (a sensor or command offset), not a force on the arm")
    for a in added:
        if a["name"] in ("stribeck_friction", "asymmetric_friction"):
            out.append(f"{a['name']} at {a['target']}: no MuJoCo field carries it (reported only)")
    return out
