"""`bench perf`: its help, its command line and the lines it prints over `bench.api.perf` (the measurements and
what they mean are `bench.api.throughput`'s)."""

from __future__ import annotations

from typing import Any

from bench.api.throughput import SCENE_FLAGS, PerfConfig, perf
from bench.api.throughput import __doc__ as ABOUT
from bench.core import config as config_mod


def help_text() -> str:
    return config_mod.command_help(
        "usage: bench perf [suite=held_out_robots] [robot=Panda] [episodes=8] [workers=2] [scaling_episodes=40]",
        ABOUT or "",
        PerfConfig,
        [
            "bench perf                                   # held_out_robots, first cell (Panda)",
            "bench perf suite=held_out_envs task=reach-v3 scaling_episodes=0",
            "bench perf obs=rgb cameras=[agentview] image_size=128 scaling_episodes=0   # rendering cost, video cost",
            "bench perf scaling_episodes=0 out=perf.json   # the measurements as JSON too",
            "bench perf vector=[1,8,32] horizon=50 scaling_episodes=0   # vectorised episodes, the packaged BC",
        ],
    )


def _print_step(stage: str, doc: dict[str, Any]) -> None:
    """The line(s) `bench perf` prints as a measurement is done."""
    cfg = doc["config"]
    with_cams = cfg["obs"] != "state"
    if stage == "start":
        print(
            f"machine: {doc['machine']['cores']} cores; suite {doc['suite']}, cell {doc['cell']}, horizon "
            f"{doc['horizon']}, random policy"
            + (f"; obs={cfg['obs']}, {cfg['image_size']}x{cfg['image_size']} images" if with_cams else "")
        )
    elif stage == "render_ms":
        flags = ", ".join(f"{k} {'on' if v else 'off'}" for k, v in SCENE_FLAGS.items())
        print("rendering: " + ", ".join(f"{c} {ms:.1f} ms/frame" for c, ms in doc["render_ms"].items()) + f" ({flags})")
    elif stage == "harness_vs_bare":
        a = doc["harness_vs_bare"]
        print(
            f"harness {a['harness_steps_per_s']:.1f} env-steps/s, bare loop {a['bare_steps_per_s']:.1f} env-steps/s "
            f"({a['steps']} steps each{', both rendering every step' if with_cams else ''}): "
            f"harness / bare = {a['ratio']:.3f}"
        )
    elif stage == "video":
        v = doc["video"]
        print(
            f"video: {v['video_steps_per_s']:.1f} env-steps/s filming every episode, {v['plain_steps_per_s']:.1f} "
            f"without: wall time x{v['wall_ratio']:.3f}"
        )
    elif stage == "vector":
        v = doc["vector"]
        rates = ", ".join(f"N={n} {r:.1f}" for n, r in v["steps_per_s"].items())
        gains = ", ".join(f"{n} / {next(iter(v['ratio']))} = {g:.2f}" for n, g in v["ratio"].items())
        print(f"vector (policy {v['policy']}, {v['episodes']} episodes, one worker): {rates} env-steps/s; {gains}")
        print(
            "  of which the policy's answers, per env-step: "
            + ", ".join(f"N={n} {ms:.3f} ms" for n, ms in v["policy_ms_per_step"].items())
        )
    elif stage == "scaling":
        b, w = doc["scaling"], doc["scaling"]["workers"]
        print(
            f"steady state: 1 worker {b['one']['steady']:.1f} env-steps/s, {w} workers {b['many']['steady']:.1f} "
            f"env-steps/s: {w} / 1 = {b['ratio_steady']:.3f}"
        )
        print(
            f"end to end ({cfg['scaling_episodes']} episodes, worker start-up and env builds included): 1 worker "
            f"{b['one']['end_to_end']:.1f}, {w} workers {b['many']['end_to_end']:.1f} env-steps/s: "
            f"{w} / 1 = {b['ratio_end_to_end']:.3f}"
        )
        print(
            f"workers busy in episodes (share of their wall time, start-up and the last episode's tail "
            f"excluded): 1 worker {b['one']['busy']:.3f} of {b['one']['wall']:.1f} s, {w} workers "
            f"{b['many']['busy']:.3f} of {b['many']['wall']:.1f} s"
        )


def main(argv: list[str]) -> int:
    if argv and argv[0] in ("-h", "--help"):
        print(help_text(), end="")
        return 0

    cfg: PerfConfig = config_mod.build_from_argv(PerfConfig, argv, "bench perf")
    done = perf(cfg, on_step=_print_step)
    if done.path is not None:
        print(f"measurements: {done.path}")
    return 0
