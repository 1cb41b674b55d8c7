"""`bench replay`: its help, the table it prints and the command line over `bench.api.replay`."""

from __future__ import annotations

import sys
from typing import Any

from bench.api.replays import HORIZON_LABELS, ReplayConfig, replay
from bench.core import config as config_mod
from bench.core.console import table_console


def render(doc: dict[str, Any], console: Any = None) -> None:
    """Per-joint RMSE / NRMSE table, one column pair per horizon."""
    from rich.table import Table  # rich: loaded only when something is drawn on the terminal

    console = console or table_console()
    hz = doc["horizons"]
    t = Table(
        title=f"replay of {len(doc['episodes'])} episode(s), {doc['frames']} frames at {doc['fps']:g} Hz "
        f"({doc['backend']}; k = {doc['k']} frames)",
        title_justify="left",
    )
    t.add_column("joint", overflow="fold")
    for label in hz:
        t.add_column(f"{HORIZON_LABELS[label]} RMSE", justify="right")
        t.add_column(f"{HORIZON_LABELS[label]} NRMSE", justify="right")
    fmt = lambda v: "-" if v is None else f"{v:.3g}"  # noqa: E731
    for name in doc["joints"]:
        t.add_row(name, *[fmt(hz[h]["per_joint"][name][m]) for h in hz for m in ("rmse", "nrmse")])
    t.add_section()
    t.add_row("mean", *[fmt(hz[h][m]) for h in hz for m in ("rmse", "nrmse")], style="bold")
    console.print(t)
    for note in doc.get("notes", []):
        console.print(f"note: {note}")


def help_text() -> str:
    """`bench replay --help`: the horizons, the keys (from ReplayConfig), the two backends."""
    return config_mod.command_help(
        "usage: bench replay logs=DIR spec=SPEC [k=10] [episodes=[0,3]] [out=DIR] [plot=2] [threads=1]\n"
        "                    [backend=mujoco|mjx] [perturb.AXIS=[levels]|uniform(lo,hi)] [worlds=1] [seed=0]\n"
        "       bench replay logs=DIR suite=held_out_robots [commands=ctrl|action] [k=10] [episodes=[..]] [out=DIR] "
        "[threads=1]",
        "Open-loop replay: each logged episode is replayed from its logged states under its logged\n"
        "commands, and the simulated joint positions are compared with the logged ones, per joint:\n"
        "RMSE and NRMSE (RMSE / std of the logged position) at three horizons:\n"
        "  one-step   re-initialised from the logged state every frame, one frame ahead\n"
        "  k-step     re-initialised every k frames, k frames ahead\n"
        "  free run   initialised once at the episode start, to its end\n"
        "The model is replayed as given (no fitting: `bench calibrate` fits it). docs/replay.md.",
        ReplayConfig,
        notes="logs=: a LeRobot v3 dataset folder (`bench logs import` converts CSV / MAT / RLDS).\n"
        "spec=: a signal map (YAML/JSON, docs/replay.md): the MJCF model, substeps per frame and the log\n"
        "columns of qpos, qvel (optional) and ctrl; a calibration spec works too (its own fields are\n"
        "ignored); all segments run batched in mujoco.rollout.\n"
        "suite=: for datasets written by `bench run ... record=DIR` (they carry the MuJoCo state before\n"
        "each step), replayed in the suite's nominal env. commands=ctrl replays the logged inputs of every\n"
        "physics step (actuator commands; Meta-World: and the mocap pose), batched in mujoco.rollout (the\n"
        "physics alone; default when the log has action.ctrl, as robosuite and Meta-World recordings do);\n"
        "commands=action feeds the logged policy actions through the env's controller in a Python step loop\n"
        "(physics and controller).\n"
        "backend=mjx: the spec's segments in one compiled MJX call (the mjx extra; docs/mjx.md).\n"
        "perturb.AXIS=...: also replay in perturbed worlds (model axes of bench run; worlds= draws per range), all\n"
        "worlds of a horizon in one batched call; one record per world in replay.json's sweep.\n"
        "out=: replay.json (schema bench.replay/1) and replay.png (logged vs replayed); never the logs or\n"
        "inside them.",
        examples=[
            "bench calibrate generate effect=payload_mass out=/tmp/case",
            "bench replay logs=/tmp/case/logs spec=/tmp/case/spec.yaml k=20 out=/tmp/case/replay",
            "bench run robots=[Panda] episodes=2 record=/tmp/rec && bench replay logs=/tmp/rec suite=held_out_robots",
        ],
    )


def main(argv: list[str]) -> int:
    """Entry point of `bench replay`."""
    if argv and (argv[0] == "help" or any(a in ("-h", "--help") for a in argv)):
        print(help_text(), end="")
        return 0
    cfg: ReplayConfig = config_mod.build_from_argv(ReplayConfig, argv, "bench replay")
    done = replay(cfg)
    doc = done.replay.doc
    render(doc)
    if done.path is not None:
        extra = f" and {done.path.parent / doc['plot']}" if doc.get("plot") else ""
        print(f"wrote {done.path}{extra} ({doc['wall_s']:.2f} s)", file=sys.stderr)
    return 0
