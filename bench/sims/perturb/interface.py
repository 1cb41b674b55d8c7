"""The interface axes, one row each, and their wrapper: the env seen through a held, delayed and noisy
command and a noisy observation.

`bench.sims.perturb.reset.apply` wraps an env with a row's `wrap` for a condition on `latency`,
`action_noise`, `obs_noise` or `action_hold`; every draw comes from the episode's generator.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable

import numpy as np

from bench.protocols import STATE, EnvAdapter, Obs
from bench.protocols.env import AdapterWrapper
from bench.sims.perturb.axis import MAX_STEPS, Axis, Params, Wrap


class PerturbedInterface(AdapterWrapper):
    """The env seen through a perturbed interface: command hold, latency, action and observation noise.

    Per step: the policy's command is sampled every `action_hold` steps (zero-order hold),
    delayed by `latency` steps (the queue starts with the neutral action: the env's
    `hold_action()` after reset where it declares one, absolute position goals holding the start
    as a delayed servo keeps its last goal; else zeros clipped to the bounds), perturbed by Gaussian
    noise with std `action_noise` x half-range and
    clipped to the bounds; the state observation gets Gaussian noise with std `obs_noise`.
    All draws come from the episode's generator.
    """

    def __init__(
        self,
        env: EnvAdapter,
        rng: np.random.Generator,
        latency: float = 0,  # whole control steps (an integer axis' level)
        action_noise: float = 0.0,
        obs_noise: float = 0.0,
        action_hold: float = 1,  # whole control steps
    ):
        super().__init__(env)
        self.env, self.rng = env, rng
        self.latency, self.action_noise = int(latency), float(action_noise)
        self.obs_noise, self.action_hold = float(obs_noise), max(1, int(action_hold))
        self.low = np.asarray(env.action_spec.low, dtype=np.float64)
        self.high = np.asarray(env.action_spec.high, dtype=np.float64)
        half = (self.high - self.low) / 2.0
        self._half = np.where(np.isfinite(half), half, 1.0)
        self.neutral = np.clip(np.zeros_like(self.low), self.low, self.high)
        self._reset_state()

    def _reset_state(self, neutral: np.ndarray | None = None) -> None:
        start = self.neutral if neutral is None else np.clip(np.asarray(neutral, np.float64), self.low, self.high)
        self._queue: deque[np.ndarray] = deque([start.copy() for _ in range(self.latency)])
        self._held = start.copy()
        self._t = 0

    def _obs(self, obs: Obs) -> Obs:
        if self.obs_noise <= 0 or STATE not in obs:
            return obs
        state = obs[STATE]
        noisy = state + self.rng.normal(0.0, self.obs_noise, size=np.shape(state))
        return {**obs, STATE: noisy.astype(np.asarray(state).dtype, copy=False)}

    def reset(self, seed: int) -> Obs:
        obs = self.env.reset(seed)
        self._reset_state(super().hold_action())  # the inner env's (None: zeros)
        return self._obs(obs)

    def edit_start(self, edit: Callable[[], None]) -> Obs:
        obs = super().edit_start(edit)
        self._reset_state(super().hold_action())  # the servos' goals followed the edited start
        return self._obs(obs)  # the edited start seen through the noisy interface too

    def step(self, action: np.ndarray) -> tuple[Obs, float, bool, bool, dict[str, object]]:
        if self._t % self.action_hold == 0:
            self._held = np.asarray(action, dtype=np.float64).copy()
        self._t += 1
        self._queue.append(self._held)
        executed = self._queue.popleft()
        if self.action_noise > 0:
            executed = executed + self.rng.normal(0.0, 1.0, size=executed.shape) * self.action_noise * self._half
            executed = np.clip(executed, self.low, self.high)
        obs, reward, terminated, truncated, info = self.env.step(executed.astype(np.float32))
        return self._obs(obs), reward, terminated, truncated, info


def _wrap(name: str) -> Wrap:
    """The row's hook: the env behind an interface perturbed on `name` alone (the others at their defaults)."""

    def wrap(env: EnvAdapter, rng: np.random.Generator, level: float) -> tuple[EnvAdapter, Params]:
        return PerturbedInterface(env, rng, **{name: level}), {}

    return wrap


ROWS: tuple[Axis, ...] = (
    Axis(
        "latency",
        "interface",
        "control steps",
        "action delay",
        "the env executes the action commanded this many control steps ago (at the start: the env's hold action, else zeros)",
        integer=True,
        nominal=0.0,
        maximum=MAX_STEPS,
        wrap=_wrap("latency"),
    ),
    Axis(
        "action_noise",
        "interface",
        "std as a fraction of the action half-range",
        "Gaussian action noise",
        "Gaussian noise added to every executed action, then clipped to the bounds",
        nominal=0.0,
        maximum=10.0,
        wrap=_wrap("action_noise"),
    ),
    Axis(
        "obs_noise",
        "interface",
        "std in observation units",
        "Gaussian observation noise",
        "Gaussian noise added to every state observation the policy sees",
        nominal=0.0,
        maximum=1e6,
        wrap=_wrap("obs_noise"),
    ),
    Axis(
        "action_hold",
        "interface",
        "control steps",
        "command held k steps (control rate / k)",
        "control-rate change: the policy's command is sampled every k steps and held (rate / k)",
        minimum=1.0,
        integer=True,
        maximum=MAX_STEPS,
        wrap=_wrap("action_hold"),
    ),
)
