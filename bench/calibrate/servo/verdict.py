"""The calibration's verdict per held-out run: which held-out metric the calibrated servo improved and which it did not.

An "after" counts only on data new to the fit and only where the calibrated simulator predicts that data better, so
every metric is judged on its own: the free-run error (from the first logged state to the end), the k-step error
(windows of `horizon` seconds started from the logged state) and, on runs with the torque off part of the time, the
free-run error over those frames. A run whose metrics disagree is reported as mixed with the metric that got worse
and, for the k-step error, where: the windows with the torque on throughout, or those with it off part of the time
(on the XL330's lift_and_drop runs at kp 100 and 200 the load-dependent friction slows the torque-on lift while it
fixes the free fall: docs/calibration.md, "Position servos").
"""

from __future__ import annotations

from typing import Any

# the held-out metrics judged, in the order they are reported: (key in the errors, name in the verdict)
METRICS: tuple[tuple[str, str], ...] = (
    ("free_run_rmse", "free-run"),
    ("k_step_rmse", "k-step"),
    ("free_fall_rmse", "torque off"),
)
# where a k-step error comes from: windows with the torque on throughout, windows with it off part of the time
K_STEP_PARTS: tuple[tuple[str, str], ...] = (
    ("k_step_rmse_torque_on", "torque-on windows"),
    ("k_step_rmse_torque_off", "windows with the torque off"),
)


def run_verdict(before: dict[str, Any], after: dict[str, Any]) -> dict[str, Any]:
    """One held-out run's errors before (declared servo) and after (calibrated): per metric both values and whether
    the after is lower; `verdict` is "better" (every metric lower), "worse" (none) or "mixed"."""
    metrics: dict[str, Any] = {}
    for key, name in METRICS:
        b, a = before.get(key), after.get(key)
        if b is None or a is None:
            continue
        metrics[name] = {"declared": float(b), "final": float(a), "better": bool(a < b)}
    better = [n for n, m in metrics.items() if m["better"]]
    worse = [n for n, m in metrics.items() if not m["better"]]
    out: dict[str, Any] = {
        "verdict": "better" if not worse else ("worse" if not better else "mixed"),
        "better_on": better,
        "worse_on": worse,
        "metrics": metrics,
    }
    if "k-step" in worse:
        out["k_step_parts"] = {
            name: {"declared": before[key], "final": after[key], "better": bool(after[key] < before[key])}
            for key, name in K_STEP_PARTS
            if before.get(key) is not None and after.get(key) is not None
        }
    return out


def verdicts(errors: dict[str, Any], heldout: list[str]) -> dict[str, Any]:
    """Every held-out run's verdict, and how many runs the calibration predicts better on every metric."""
    per_run = {n: run_verdict(errors["declared"][n], errors["final"][n]) for n in heldout}
    counted = [n for n, v in per_run.items() if v["verdict"] == "better"]
    return {
        "rule": "an after counts on a held-out run only if the calibrated servo predicts it better on every held-out "
        "metric (free-run, k-step, and torque off where the run has it)",
        "runs_better_on_every_metric": len(counted),
        "runs": len(per_run),
        "per_run": per_run,
    }


def _explain(v: dict[str, Any]) -> str:
    """What did not improve on one run, with the numbers (and where the k-step error grew)."""
    parts = []
    for name in v["worse_on"]:
        m = v["metrics"][name]
        text = f"{name} {m['declared']:.4f} -> {m['final']:.4f} rad (worse)"
        if name == "k-step" and v.get("k_step_parts"):
            text += ": " + ", ".join(
                f"{where} {p['declared']:.4f} -> {p['final']:.4f}" for where, p in v["k_step_parts"].items()
            )
        parts.append(text)
    better = ", ".join(v["better_on"]) or "nothing"
    return "; ".join(parts) + f"; better on {better}"


def verdict_lines(errors: dict[str, Any], heldout: list[str], labels: dict[str, str]) -> list[str]:
    """Console and report lines: how many held-out runs are predicted better on every metric, then one line per run
    that is not, naming the metric that did not improve. `labels` gives each run's description (trajectory, gain)."""
    v = verdicts(errors, heldout)
    lines = [
        f"held-out runs predicted better on every metric (free-run, k-step, torque off): "
        f"{v['runs_better_on_every_metric']} of {v['runs']}"
    ]
    for name, rv in v["per_run"].items():
        if rv["verdict"] != "better":
            lines.append(f"NOT better on every metric: {name} ({labels.get(name, '')}): {_explain(rv)}")
    return lines
