"""ManiSkill on a GPU: env-steps/s of PickCube at num_envs = 1, 64, 1024, 4096, raw and through the harness.

    python benchmarks/bench_maniskill_gpu.py [task=PickCube] [sizes=1,64,1024,4096] [steps=200]

Raw: `gym.make("<task>-v1", num_envs=N, sim_backend="physx_cuda", obs_mode="state",
control_mode="pd_joint_delta_pos", render_backend="none")` stepped with random actions drawn on the
device (ManiSkill's own benchmark style). Harness: `bench.sims.maniskill_vec.ManiSkillVecEnv` with the
same N, actions from numpy and observations/rewards/success back to numpy every step (what a
per-episode record needs). Both reset first; steps/s = N x steps / wall time. Needs a CUDA GPU;
without one it says so and exits 2. Compare with ManiSkill's own published GPU throughput figures
on the same GPU class.
"""

from __future__ import annotations

import sys
import time
from typing import Any

from bench.api.scripts import script_keys


def main(argv: list[str]) -> int:
    opts = script_keys(argv, __doc__, ("sizes", "steps", "task"))
    task = opts.get("task", "PickCube")
    sizes = [int(x) for x in opts.get("sizes", "1,64,1024,4096").split(",")]
    steps = int(opts.get("steps", 200))
    import torch

    if not torch.cuda.is_available():
        print(
            "bench_maniskill_gpu: no CUDA device on this machine (torch.cuda.is_available() is False); "
            "nothing to measure",
            file=sys.stderr,
        )
        return 2
    import gymnasium as gym
    import mani_skill.envs  # noqa: F401
    import numpy as np

    from bench.sims.maniskill import NativeInterface
    from bench.sims.maniskill_vec import ManiSkillVecEnv

    env_id = f"{task}-v1"
    print(f"{env_id}, state observations, pd_joint_delta_pos, {steps} steps per size, {torch.cuda.get_device_name()}")
    for n in sizes:
        raw: Any = gym.make(
            env_id,
            num_envs=n,
            sim_backend="physx_cuda",
            obs_mode="state",
            control_mode="pd_joint_delta_pos",
            render_backend="none",
        )
        raw.reset(seed=0)
        space = raw.action_space
        low = torch.as_tensor(space.low, device=raw.unwrapped.device)
        high = torch.as_tensor(space.high, device=raw.unwrapped.device)
        for _ in range(10):
            raw.step(low + (high - low) * torch.rand_like(low))
        torch.cuda.synchronize()
        t0 = time.perf_counter()
        for _ in range(steps):
            raw.step(low + (high - low) * torch.rand_like(low))
        torch.cuda.synchronize()
        raw_rate = n * steps / (time.perf_counter() - t0)
        raw.close()
        vec = ManiSkillVecEnv(env_id, "panda", n, interface=NativeInterface("pd_joint_delta_pos"))
        vec.reset(list(range(n)))
        rng = np.random.default_rng(0)
        lo, hi = vec.action_spec.low, vec.action_spec.high
        acts = rng.uniform(lo, hi, size=(steps + 10, n, len(lo))).astype(np.float32)
        for a in acts[:10]:
            vec.step(a)
        t0 = time.perf_counter()
        for a in acts[10:]:
            vec.step(a)
        vec_rate = n * steps / (time.perf_counter() - t0)
        vec.close()
        print(
            f"  num_envs={n:>5}: raw {raw_rate:>10.0f} env-steps/s, harness {vec_rate:>10.0f} env-steps/s "
            f"(harness / raw = {vec_rate / raw_rate:.3f})"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
