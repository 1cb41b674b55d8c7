"""ManiSkill's own motion-planning solutions as closed-loop policies (`act(obs) -> action`).

A solution (`mani_skill.examples.motionplanning.panda.solutions`, or one of ours in
`baselines.maniskill_solutions`) drives an env itself: it plans a screw motion with mplib from the
robot's current state, then calls `env.step` once per waypoint, re-plans from where the robot
ended, and so on. Here it runs in a helper thread against a proxy env whose `step` hands the
action to the harness and blocks until the harness has executed it; the harness's own env (with
its perturbations, noise and latency) takes every step, and the solution reads the true state
between steps exactly as it does when it owns the env. The two threads strictly alternate, so the
simulator is never touched concurrently. When the solution returns, the policy holds its last
command. Planning is deterministic (screw motions), so a seed gives the same episode twice.

Solutions command `pd_joint_pos` (7 joint targets + gripper, +1 open / -1 closed), so this
policy requires that control mode.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable
from typing import Any

import numpy as np

from bench.api import ConfigError

CONTROL_MODE = "pd_joint_pos"
_STEPPED, _ABORT = "stepped", "abort"


class _Abort(BaseException):
    """Unwinds a solution whose episode the harness has ended (not an error)."""


class _EnvProxy:
    """The env a solution sees: `unwrapped` is the real ManiSkill env, `step` goes through the harness."""

    def __init__(self, base: Any, to_harness: queue.Queue, to_solver: queue.Queue, success: Callable[[], bool]):
        self.unwrapped = base
        self._to_harness, self._to_solver, self._success = to_harness, to_solver, success

    def reset(self, *args: Any, **kwargs: Any) -> tuple[dict, dict]:
        return {}, {}  # the harness has already reset the env with the episode's seed

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict]:
        self._to_harness.put(("action", np.asarray(action, dtype=np.float32)))
        if self._to_solver.get() == _ABORT:
            raise _Abort()
        import torch

        return None, 0.0, False, False, {"success": torch.tensor([self._success()])}


class MotionPlanExpert:
    """A motion-planning solution `solve(env, seed=None, debug=False, vis=False)` as a Policy."""

    def __init__(self, env: Any, solve: Callable[..., Any], name: str = ""):
        if env.base.control_mode != CONTROL_MODE:
            which = f" for {name}" if name else ""
            raise ConfigError(
                f"control_mode={env.base.control_mode!r}: the motion-planning expert{which} "
                f"commands {CONTROL_MODE}; run it with control_mode={CONTROL_MODE}"
            )
        self.env, self.solve, self.name = env, solve, name
        self._thread: threading.Thread | None = None
        self._to_harness: queue.Queue = queue.Queue()
        self._to_solver: queue.Queue = queue.Queue()
        self._waiting = False  # the solution is blocked in step() waiting for the harness
        self._finished = False
        self._hold: np.ndarray | None = None

    def reset(self, seed: int | None = None) -> None:
        self._stop()
        self._to_harness, self._to_solver = queue.Queue(), queue.Queue()
        self._finished, self._hold = False, None

    def act(self, obs: Any) -> np.ndarray:
        if self._finished:
            return self._hold_action()
        if self._thread is None:
            self._start()
        elif self._waiting:
            self._to_solver.put(_STEPPED)
        kind, payload = self._to_harness.get()
        self._waiting = kind == "action"
        if kind == "action":
            self._hold = payload
            return payload
        self._thread = None
        self._finished = True
        if kind == "error":
            raise RuntimeError(
                f"motion-planning solution {self.name} failed: {type(payload).__name__}: {payload}"
            ) from payload
        return self._hold_action()

    def close(self) -> None:
        self._stop()

    def __del__(self) -> None:  # a policy dropped mid-episode (e.g. after a timeout) must not leave its thread blocked
        self._stop()

    def _start(self) -> None:
        proxy = _EnvProxy(self.env.base, self._to_harness, self._to_solver, self.env.success)
        out, solve = self._to_harness, self.solve  # the thread holds no reference to the policy itself

        def run() -> None:
            try:
                solve(proxy, seed=None, debug=False, vis=False)
                out.put(("done", None))
            except _Abort:
                pass
            except Exception as exc:  # handed to the harness thread, which records it
                out.put(("error", exc))

        self._thread = threading.Thread(target=run, name=f"mp-{self.name}", daemon=True)
        self._thread.start()

    def _stop(self) -> None:
        thread, self._thread = getattr(self, "_thread", None), None
        if thread is not None and thread.is_alive():
            self._to_solver.put(_ABORT)
            if thread is not threading.current_thread():
                thread.join(timeout=10)
        self._waiting = False

    def _hold_action(self) -> np.ndarray:
        if self._hold is None:  # the solution never moved: hold the arm where it is, gripper open
            qpos = self.env.base.agent.robot.get_qpos()[0].cpu().numpy()
            dim = self.env.action_spec.dim
            self._hold = np.append(qpos[: dim - 1], 1.0).astype(np.float32)
        return self._hold
