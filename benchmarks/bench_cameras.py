"""Cameras: rendering cost, harness overhead with image observations, video cost, memory over a long run.

    python benchmarks/bench_cameras.py [--suite held_out_robots] [--robot Panda] [--camera agentview]
                                       [--size 128] [--episodes 6] [--horizon 60] [--long 200] [--long-horizon 20]

Measured in one run, one process, the random policy (actions depend only on the episode seed):

1. rendering: median ms per frame of the camera (MuJoCo offscreen, EGL; scene settings printed).
2. harness / bare loop with `obs=rgb` and one camera: the harness's per-episode path (policy,
   perturbation wrapper, checks, record written and fsynced) against a bare loop that resets and
   steps the same camera-wrapped env (which renders the same camera every step). Target >= 0.95.
3. video: the harness filming every episode (`video=N`: frames copied to a background H.264
   encoder) against the same episodes unfilmed. Target: wall time x <= 1.10.
4. memory: resident set size after episode 10 and after the last of a `--long`-episode camera
   run, every episode filmed (renderer, frame buffers and encoder threads would leak here).

Speeds on a shared machine move with its load: the ratios are measured in one run, alternating
the two sides episode by episode, so a change of load hits both alike.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench import api
from bench.api import throughput as perf  # noqa: E402
from bench.sims.camera import SCENE_FLAGS  # noqa: E402


def rss_mb() -> float:
    """Resident set size of this process in MiB (Linux /proc)."""
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def long_run(p, episodes: int) -> dict[str, float]:
    """RSS after episode 10 and after the last one of `episodes` filmed camera episodes in one worker."""
    with tempfile.TemporaryDirectory() as tmp:
        ctx = dataclasses.replace(api.context(p), video_dir=tmp, video_episodes=episodes)
        worker = api.worker(p, ctx)
        out: dict[str, float] = {}
        t0 = time.perf_counter()
        try:
            for job in p.jobs[:episodes]:
                rec = worker.run(job)
                if rec.error:
                    raise RuntimeError(f"episode {job.episode} failed: {rec.error}")
                for f in Path(tmp, "videos").glob("*.mp4"):  # keep the disk flat too
                    f.unlink()
                if job.episode + 1 in (1, 10, episodes):
                    out[f"rss_mb_after_{job.episode + 1}"] = rss_mb()
        finally:
            worker.close()
        out["seconds"] = time.perf_counter() - t0
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--suite", default="held_out_robots")
    ap.add_argument("--robot", default="Panda")
    ap.add_argument("--task", default=None)
    ap.add_argument("--camera", default="agentview")
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--episodes", type=int, default=6, help="episodes for the harness and video ratios")
    ap.add_argument("--horizon", type=int, default=60)
    ap.add_argument("--long", type=int, default=200, help="episodes of the memory run")
    ap.add_argument("--long-horizon", type=int, default=20, help="steps per episode of the memory run")
    args = ap.parse_args()
    cfg = perf.PerfConfig(
        suite=args.suite,
        robot=args.robot if args.suite != "held_out_envs" else None,
        task=args.task,
        episodes=args.episodes,
        horizon=args.horizon,
    )
    options = {"obs": "rgb", "cameras": [args.camera], "image_size": args.size}
    p = perf.make_plan(cfg, args.episodes, options)
    flags = ", ".join(f"{k} {'on' if v else 'off'}" for k, v in SCENE_FLAGS.items())
    print(
        f"{os.cpu_count()} cores, MUJOCO_GL={os.environ.get('MUJOCO_GL', '(unset: egl)')}; {p.suite.name} "
        f"{p.cells[0].key}, obs=rgb, camera {args.camera} {args.size}x{args.size} ({flags}), random policy"
    )
    cost = perf.render_cost(p)
    print(f"rendering            {cost[args.camera]:.2f} ms/frame (median)")
    a = perf.harness_vs_bare(p)
    print(
        f"harness / bare loop  {a['ratio']:.3f}   (harness {a['harness_steps_per_s']:.1f}, bare "
        f"{a['bare_steps_per_s']:.1f} env-steps/s over {a['steps']} steps; target >= 0.95)"
    )
    v = perf.video_overhead(p)
    print(
        f"video wall time      x{v['wall_ratio']:.3f}  (filmed {v['video_steps_per_s']:.1f}, plain "
        f"{v['plain_steps_per_s']:.1f} env-steps/s; target <= 1.10)"
    )
    if args.long:
        cfg_long = dataclasses.replace(cfg, horizon=args.long_horizon)
        m = long_run(perf.make_plan(cfg_long, args.long, options), args.long)
        print(
            f"memory               RSS {m['rss_mb_after_1']:.0f} MiB after episode 1, {m['rss_mb_after_10']:.0f} MiB "
            f"after episode 10, {m[f'rss_mb_after_{args.long}']:.0f} MiB after episode {args.long} "
            f"({args.long} filmed episodes of {args.long_horizon} steps in {m['seconds']:.0f} s)"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
