"""Error rates of `bench regress` on real rollouts: false alarms on identical checkpoints, detections on a degraded one.

    python benchmarks/bench_regress.py                       # trains a tiny BC checkpoint first
    python benchmarks/bench_regress.py --checkpoint runs/bc/policy.safetensors --gates 20

(The decision rule's error rates on synthetic outcomes, with per-cell tests: benchmarks/bench_gate.py.)

What it does (a benchmark, not a test: it prints counts and takes minutes):
1. A checkpoint: `--checkpoint`, or a behaviour-cloning MLP trained here (40 scripted-expert
   demonstrations per robot recorded with `bench run record=`, fitted with `baselines.bc` defaults).
2. A degraded copy: the same spec with Gaussian noise added to every weight tensor
   (`--noise` x that tensor's std), saved with `save_checkpoint` (another sha256).
3. `--gates` gates of a re-saved copy of the checkpoint (same weights, one more metadata entry,
   so another sha256: the gate cannot skip it as identical) against the checkpoint, each with a
   fresh run seed: the false-alarm count (target <= 1 of 20). Then `--gates` gates of the
   degraded copy against the checkpoint, fresh seeds again: the detection count. Every gate is a
   full `bench regress` (both sides simulated, paired by episode seed, sequential looks), run in
   this process with workers=1.

Measured before the per-cell tests (2 shared cores, defaults: Panda+IIWA, up to 6 episodes per
cell in looks of 3, horizon 150; BC success 0.87): false alarms 0 / 20 (paired outcomes
identical in every gate), detections 20 / 20 (degraded success 0.00, 4.2 episodes per cell used
on average); 1817 s in all. Synthetic rates: docs/ci-gate.md.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def train_tiny_bc(work: Path, robots: list[str], episodes: int, horizon: int) -> Path:
    """Record scripted-expert demos on `robots` and fit a BC MLP on them (baselines.bc defaults)."""
    from baselines import bc
    from bench.cli import run

    demos = work / "demos"
    if not (demos / "meta").exists():
        with _quiet():
            run.main(
                [
                    "policy=scripted",
                    f"robots=[{','.join(robots)}]",
                    f"episodes={episodes}",
                    f"horizon={horizon}",
                    "workers=1",
                    "seed=12345",
                    f"out={work / 'runs'}",
                    "run_id=demos",
                    f"record={demos}",
                ]
            )
    path, info = bc.train(bc.Args(data=[str(demos)], out=str(work / "bc" / "policy.safetensors"), seed=0))
    print(
        f"trained {path}: {info['frames']} frames from {info['episodes']} episodes in {info['train_wall_s']} s, "
        f"final loss {info['final']['loss']:.4f}"
    )
    return path


def degrade(ckpt: Path, out: Path, noise: float, seed: int = 0) -> Path:
    """A copy of `ckpt` with N(0, (noise * std(tensor))^2) added to every weight tensor."""
    import torch
    from safetensors.torch import load_file

    from baselines.architectures import build
    from baselines.checkpoint import load_spec, read_weights, save_checkpoint

    tensors, meta = read_weights(ckpt)
    spec = load_spec(ckpt, meta)
    gen = torch.Generator().manual_seed(seed)
    noisy = {
        k: v + noise * (v.std() if v.numel() > 1 else v.abs()) * torch.randn(v.shape, generator=gen)
        for k, v in load_file(str(ckpt)).items()
    }
    model = build(spec["architecture"], spec["obs_dim"], spec["action_dim"], spec["kwargs"])
    model.load_state_dict(noisy)
    return save_checkpoint(out, model, spec)


def resave(ckpt: Path, out: Path) -> Path:
    """The same weights and spec saved again with one more `meta` entry: the same policy, another sha256."""
    from safetensors.torch import load_file

    from baselines.architectures import build
    from baselines.checkpoint import load_spec, read_weights, save_checkpoint

    _, meta = read_weights(ckpt)
    spec = load_spec(ckpt, meta)
    model = build(spec["architecture"], spec["obs_dim"], spec["action_dim"], spec["kwargs"])
    model.load_state_dict(load_file(str(ckpt)))
    return save_checkpoint(out, model, {**spec, "meta": {**(spec.get("meta") or {}), "resaved_from": ckpt.name}})


@contextlib.contextmanager
def _quiet():
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(buf):
        yield buf


def gate(candidate: str, baseline: str, seed: int, a, work: Path, name: str) -> dict:
    """One `bench regress` in-process; returns the verdict document (exit code included)."""
    from bench.cli import regress
    from bench.core.errors import BenchError

    out = work / "gates" / f"{name}.json"
    argv = [
        f"candidate={candidate}",
        f"baseline={baseline}",
        f"seed={seed}",
        f"robots=[{a.robots}]",
        f"episodes={a.episodes}",
        f"batch={a.batch}",
        f"horizon={a.horizon}",
        "workers=1",
        f"runs={work / 'gates'}",
        f"run_id={name}",
        f"out={out}",
    ]
    with _quiet() as buf:
        try:
            code = regress.main(argv)
        except BenchError as exc:
            raise SystemExit(f"gate {name} failed: {exc}\n{buf.getvalue()[-2000:]}") from None
    doc = json.loads(out.read_text())
    assert doc["exit_code"] == code
    return doc


def series(label: str, candidate: str, baseline: str, seeds: range, a, work: Path) -> list[dict]:
    docs = []
    for i, seed in enumerate(seeds):
        t0 = time.time()
        d = gate(candidate, baseline, seed, a, work, f"{label}-{seed}")
        last = d["looks"][-1]
        c = d["cells"]
        rates = " ".join(f"{x['robot']} {x['baseline']:.2f}/{x['candidate']:.2f}" for x in c)
        print(
            f"  {label} gate {i + 1:2d} seed {seed}: {d['verdict']:<13} exit {d['exit_code']}  "
            f"drop {last['mean']['value']:+.2f} [{last['mean']['lcb']:+.2f}, {last['mean']['ucb']:+.2f}]  "
            f"{last['episodes_per_cell']} ep/cell  base/cand {rates}  ({time.time() - t0:.0f} s)",
            flush=True,
        )
        docs.append(d)
    return docs


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkpoint", help="checkpoint to gate (default: train a tiny BC one)")
    ap.add_argument("--gates", type=int, default=20, help="gates per series (identical, degraded)")
    ap.add_argument("--robots", default="Panda,IIWA", help="robots of held_out_robots to run (comma-separated)")
    ap.add_argument("--episodes", type=int, default=6, help="max episodes per cell per gate")
    ap.add_argument("--batch", type=int, default=3, help="episodes per cell between looks")
    ap.add_argument("--horizon", type=int, default=150, help="control steps per episode")
    ap.add_argument("--noise", type=float, default=1.0, help="degradation: weight noise in units of each tensor's std")
    ap.add_argument("--demo-episodes", type=int, default=40, help="expert episodes per robot for the BC checkpoint")
    ap.add_argument("--work", default="/tmp/bench_regress", help="scratch folder (demos, checkpoints, gate runs)")
    a = ap.parse_args()
    work = Path(a.work)
    work.mkdir(parents=True, exist_ok=True)
    robots = a.robots.split(",")
    t0 = time.time()
    if a.gates:
        ckpt = Path(a.checkpoint) if a.checkpoint else train_tiny_bc(work, robots, a.demo_episodes, 150)
        bad = degrade(ckpt, work / "degraded" / "policy.safetensors", a.noise)
        print(
            f"config: suite held_out_robots, robots {robots}, up to {a.episodes} episodes per cell in looks of "
            f"{a.batch}, horizon {a.horizon}, margin 0.05, alpha 0.05, workers=1; checkpoint {ckpt}, degraded copy "
            f"{bad} (noise {a.noise} x std)"
        )
        copy = resave(ckpt, work / "copy" / "policy.safetensors")
        same = series("same weights", str(copy), str(ckpt), range(1000, 1000 + a.gates), a, work)
        worse = series("degraded", str(bad), str(ckpt), range(2000, 2000 + a.gates), a, work)
        fa = sum(d["exit_code"] == 1 for d in same)
        det = sum(d["exit_code"] == 1 for d in worse)
        base_rate = np.mean([c["baseline"] for d in same + worse for c in d["cells"]])
        bad_rate = np.mean([c["candidate"] for d in worse for c in d["cells"]])
        identical_pairs = all(d["looks"][-1]["baseline_only"] == d["looks"][-1]["candidate_only"] == 0 for d in same)
        print(
            f"\nfalse alarms (re-saved copy vs checkpoint, fresh seeds): {fa} / {len(same)}   "
            f"[paired outcomes identical in every gate: {identical_pairs}]"
        )
        print(
            f"detections (degraded copy vs checkpoint, fresh seeds): {det} / {len(worse)}   "
            f"[success: checkpoint {base_rate:.2f}, degraded {bad_rate:.2f}; mean ep/cell used "
            f"{np.mean([d['looks'][-1]['episodes_per_cell'] for d in worse]):.1f} of {a.episodes}]"
        )
    print(f"\ntotal {time.time() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(REPO))
    raise SystemExit(main())
