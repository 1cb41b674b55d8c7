"""The forward refinement of an arm's inverse-dynamics estimate: DIDIM (Gautier, Janot and Vandanjon, 2013).

IDIM fits the torque on the *measured* positions, velocities and (differentiated, filtered)
accelerations. DIDIM starts there and fits the torque on the states of the *simulation* instead: each
iteration simulates the training data in closed loop with the current estimate (the same loop as the
forward check, `bench.calibrate.arm.forward`), builds the regressor of the simulated positions,
velocities and accelerations (noise-free, and consistent with the model that runs), and refits by the
same weighted, physically constrained least squares. The simulated torque of the loop is exactly the
regressor times the parameters, so each step is a Gauss-Newton step of the closed-loop output error;
it converges in a few iterations. Kept is the DIDIM iterate whose closed-loop free run on the training
data is best; whether it beats IDIM's estimate is for the held-out data to say (`calibrate_arm`).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TypedDict

import numpy as np

from bench.calibrate.arm.blocks import Fitter, regression
from bench.calibrate.arm.dynamics import Dynamics
from bench.calibrate.arm.forward import Bench, Drive, Loop
from bench.calibrate.arm.idim import Fit
from bench.calibrate.arm.model import ArmModel
from bench.calibrate.arm.spec import ArmSpec
from bench.replay.simulate import free_runs

MAX_ROWS = 4000  # simulated training frames the regressor is built on (evenly thinned beyond)


class Iteration(TypedDict):
    """One DIDIM iteration's training error (iteration 0: IDIM's estimate)."""

    iteration: int
    estimate: str  # idim | didim
    train_closed_loop_free_run_nrmse: float


@dataclass
class SimSamples:
    """Simulated training states and the logged torque at the same frames."""

    q: np.ndarray
    dq: np.ndarray
    ddq: np.ndarray
    tau: np.ndarray


def simulated(bench: Bench, drive: Drive, loop: Loop) -> tuple[SimSamples, float]:
    """The training data simulated in closed loop with `drive` (thinned to MAX_ROWS) and its free-run NRMSE."""
    segs = free_runs(bench.rec, bench.train)
    sim = bench.simulate(drive, loop, segs)
    n = len(bench.am.joints)
    qs, dqs, ddqs, taus, errs = [], [], [], [], []
    spread = np.maximum(bench.rec.qpos[bench.rec.frames(bench.train)].std(axis=0), 1e-12)
    for i, s0 in enumerate(segs.start):
        valid = np.ones(segs.length, bool) if segs.mask is None else segs.mask[i]
        frames = s0 + 1 + np.flatnonzero(valid)
        q, dq = sim[i, valid, :n], sim[i, valid, n:]
        if len(q) < 3 or not np.all(np.isfinite(q)):
            continue
        qs.append(q)
        dqs.append(dq)
        ddqs.append(np.gradient(dq, 1.0 / bench.fps, axis=0))
        taus.append(bench.tau[frames])
        errs.append((q - bench.rec.qpos[frames]) ** 2)
    if not qs:
        return SimSamples(*(np.zeros((0, n)) for _ in range(4))), float("inf")
    nrmse = float(np.mean(np.sqrt(np.mean(np.concatenate(errs), axis=0)) / spread))
    out = [np.concatenate(v) for v in (qs, dqs, ddqs, taus)]
    keep = np.linspace(0, len(out[0]) - 1, min(len(out[0]), MAX_ROWS)).astype(int)
    return SimSamples(*(v[keep] for v in out)), nrmse


def refine(
    spec: ArmSpec,
    am: ArmModel,
    dyn: Dynamics,
    bench: Bench,
    loop: Loop,
    start: Fit,
    added: Sequence[Mapping[str, object]],
    drive_of: Callable[[Fit], Drive],
    log: Callable[[str], None] = lambda msg: None,
) -> tuple[Fit | None, np.ndarray | None, list[Iteration]]:
    """The DIDIM estimate (and its fixed torque on the simulated rows), and every iteration's training error
    (iteration 0: IDIM's estimate). None when there are no training windows to simulate."""
    history: list[Iteration] = []
    if not bench.train or spec.didim <= 0:
        return None, None, history
    cur = start
    best: tuple[Fit, np.ndarray] | None = None
    samples, err = simulated(bench, drive_of(cur), loop)
    history.append({"iteration": 0, "estimate": "idim", "train_closed_loop_free_run_nrmse": err})
    best_err = np.inf
    for it in range(1, spec.didim + 1):
        if len(samples.q) < 10:
            break
        rows = np.ones(len(samples.q), bool)
        reg = regression(spec, am, samples, dyn, samples.tau, rows)
        blocks = reg.blocks_of(added)
        fitter = Fitter(am, samples.tau, reg.base_free, rows, rows, reg.payload_inertia, spec.trace.criterion)
        fitter.weights = start.weights
        f, fixed = fitter(blocks, x0=cur.x)
        samples, err = simulated(bench, drive_of(f), loop)
        history.append({"iteration": it, "estimate": "didim", "train_closed_loop_free_run_nrmse": err})
        log(f"forward refinement (DIDIM) iteration {it}: training closed-loop free-run NRMSE {err:.4g}")
        cur = f
        improved = err < best_err * (1 - 1e-3)
        if err < best_err:
            best, best_err = (f, fixed), err
        if not improved:
            break  # converged (or moving away): keep the best so far
    if best is None:
        return None, None, history
    return best[0], best[1], history
