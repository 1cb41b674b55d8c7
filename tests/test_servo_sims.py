"""The servo law in every simulator: the fit's batched numpy simulator (`servo.sim`), MuJoCo CPU (`servo.mujoco`,
with backlash and the firmware's goal velocity limit) and MJX (`servo.mjx`), on a synthetic bench run (no data)."""

from __future__ import annotations

import numpy as np
import pytest

from bench.calibrate.servo.data import ServoRun
from bench.calibrate.servo.law import ServoParams, goal_step
from bench.calibrate.servo.mujoco import simulate_run
from bench.calibrate.servo.sim import make_windows, simulate, substeps_for, target_axis

XL330 = dict(kp=400.0, error_gain=0.0028775, kt_over_r=0.104, kt=0.43, inertia=0.0077, gravity=0.5, viscous=0.002)
EFFECTS = dict(play=0.05, goal_slowness=0.5, load_friction=0.2, coulomb=0.01)


def _run(fps: float = 200.0, seconds: float = 3.0) -> ServoRun:
    """A goal with a fast stretch (beyond 2 rad/s) and a step, the torque off for the last fifth."""
    t = np.arange(int(seconds * fps)) / fps
    goal = 0.8 * np.sin(3.0 * t) + 0.3 * (t > 0.5 * seconds)
    z = np.zeros_like(t)
    enable = (t < 0.8 * seconds).astype(float)
    return ServoRun("syn", fps, t, z, z, z, goal, enable, np.full_like(t, 7.4), None, "kp=400", "syn")


def _ours(p: ServoParams, r: ServoRun) -> np.ndarray:
    w = make_windows([r], [r.label], 0)
    return simulate(p.with_(kp=np.array([p.kp])), w)[0]


def _cpu(p: ServoParams, r: ServoRun) -> np.ndarray:
    return simulate_run(p, r.goal, r.enable, r.vin, 0.0, 0.0, r.fps, substeps_for(r.fps))


@pytest.mark.parametrize(
    "effects",
    [{"play": 0.05}, {"goal_slowness": 0.5}, EFFECTS],
    ids=["backlash", "goal_velocity_limit", "all"],
)
def test_mujoco_cpu_runs_the_fits_servo_with_backlash_and_the_goal_velocity_limit(effects):
    r = _run()
    p, bare = ServoParams(**XL330, **effects), ServoParams(**XL330)
    ours, cpu = _ours(p, r), _cpu(p, r)
    effect = np.sqrt(np.mean((ours - _ours(bare, r)) ** 2))  # what the effects change
    gap = np.sqrt(np.mean((cpu - ours) ** 2))
    assert effect > 0.005, effect
    assert gap < 0.1 * effect, (gap, effect)


def test_the_firmware_target_moves_at_most_its_velocity_and_resets_while_the_torque_is_off():
    r = _run()
    w = make_windows([r], [r.label], 0)
    slowness = 0.5  # 2 rad/s; the goal reaches 2.4 rad/s and steps
    y = target_axis(w, slowness)
    p = ServoParams(goal_slowness=slowness)
    ref = np.empty_like(y)  # the law's step, frame after frame
    ref[0] = r.goal[0]
    for k in range(1, y.size):
        ref[k] = goal_step(p, ref[k - 1], r.goal[k], 1.0 / r.fps) if r.enable[k] > 0.5 else r.q[k]
    assert np.allclose(y, ref, atol=1e-12)
    on = r.enable[1:] > 0.5
    assert np.max(np.abs(np.diff(y))[on]) <= 2.0 / r.fps + 1e-12
    assert np.max(np.abs(y - r.goal)) > 0.05  # it did bind


def test_mjx_steps_the_same_servo_as_mujoco_cpu():
    pytest.importorskip("jax", reason="MJX needs jax")
    from bench.calibrate.servo.mjx import simulate_run_mjx  # only here: JAX is an optional, slow import

    r = _run(fps=100.0, seconds=1.5)
    p = ServoParams(**XL330, **EFFECTS)
    cpu = _cpu(p, r)
    mjx = simulate_run_mjx(p, r.goal, r.enable, r.vin, 0.0, 0.0, r.fps, substeps_for(r.fps))
    assert mjx.shape == cpu.shape
    assert np.max(np.abs(mjx - cpu)) < 1e-4  # float32 in MJX against float64 on the CPU
    assert np.std(cpu) > 0.1  # it moved
