"""The MJX replay simulator: `bench.replay.simulate.Simulator`'s segments and variants, run by MJX.

Everything but the stepping is the CPU simulator's (initial states from the log, commands per
physics step, read-out of the logged coordinates); `_full` hands all segments of all variants to one
compiled, batched MJX call (`bench.sims.mjx.Rollouts`): variants whose models differ in some float
fields (a perturbed mass, damping or gravity) are worlds with their own values of those fields.
State-dependent forces (calibration's Stribeck effect) and models with extra coordinates (backlash)
are the CPU simulator's only.
"""

from __future__ import annotations

import numpy as np

from bench.core.errors import ConfigError
from bench.replay.data import Recording
from bench.replay.simulate import Segments, Simulator, Variant
from bench.sims import mjx as mjx_backend

PREFIXES = ("dof_", "jnt_", "body_", "actuator_", "geom_", "tendon_", "qpos_spring")


class MjxSimulator(Simulator):
    """`Simulator` whose rollouts run in MJX (JAX's default device), all segments x variants in one call."""

    backend = "mjx"

    def __init__(self, model, rec: Recording, substeps: int, threads: int = 1) -> None:
        super().__init__(model, rec, substeps, threads)
        self.rollouts = mjx_backend.Rollouts(model, substeps)
        self._fields = sorted(
            f.name
            for f in type(self.rollouts.mx).fields()
            if f.name.startswith(PREFIXES)
            and isinstance(getattr(model, f.name, None), np.ndarray)
            and getattr(model, f.name).dtype.kind == "f"
        )

    @property
    def compile_s(self) -> float:
        return self.rollouts.compile_s

    def _world(self, variants: list[Variant], n: int) -> dict[str, np.ndarray]:
        """Per-world values of the fields in which some variant's model differs from the simulator's."""
        world: dict[str, np.ndarray] = {}
        for f in self._fields:
            values = [np.asarray(getattr(v.model, f)) for v in variants]
            if any(not np.array_equal(a, getattr(self.model, f)) for a in values):
                world[f] = np.repeat(np.stack(values), n, axis=0)
        gravity = [np.asarray(v.model.opt.gravity) for v in variants]
        if any(not np.array_equal(g, self.model.opt.gravity) for g in gravity):
            world["opt.gravity"] = np.repeat(np.stack(gravity), n, axis=0)
        return world

    def _full(self, variants: list[Variant], segs: Segments, init: np.ndarray) -> np.ndarray:
        """Full [qpos, qvel] of the variants after each frame: (V * n, length, nq + nv), in one MJX call."""
        if any(v.force is not None or v.coords is not None for v in variants):
            raise ConfigError(
                "backend=mjx: a state-dependent force or a model with extra coordinates (backlash) runs on the "
                "CPU simulator only; use backend=mujoco"
            )
        m, s, n = variants[0].model, self.substeps, len(segs)
        ctrl = np.concatenate([self._controls(v, segs) for v in variants])
        qpos0 = init[:, 1 : 1 + m.nq]
        qvel0 = init[:, 1 + m.nq : 1 + m.nq + m.nv]
        world = self._world(variants, n)
        self.steps += len(variants) * n * segs.length * s
        return self.rollouts.simulate(qpos0, qvel0, ctrl, world or None, per_world=bool(world))
