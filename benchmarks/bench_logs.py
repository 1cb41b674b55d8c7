"""Read speed of LeRobot v3.0 logs: a whole dataset vs one episode, measured in one run.

    python benchmarks/bench_logs.py [episodes=1000 frames=500 dim=14 repeats=5]

Writes `episodes` x `frames` frames of `dim`-D float32 state and action to a temporary folder,
then times (wall clock, median of `repeats`):
  - read_dataset: the whole dataset, metadata caches cleared before each read (target < 1 s);
  - read_episode cold: one episode with the metadata caches cleared (info, tasks, episode table);
  - read_episode warm: one random episode with the metadata cached (target < 5 ms), the normal
    case in a loop over episodes.
The files are freshly written, so the OS page cache is warm: these are parse/convert costs, not
disk costs. CPU seconds (all threads) are printed beside wall seconds: on a shared machine the
wall clock also counts time spent waiting for a core.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.logs import from_arrays, read_dataset, read_episode, write_dataset
from bench.logs.lerobot import index as lerobot_index
from bench.logs.lerobot import read as lerobot_read


def _clear_caches() -> None:
    lerobot_index._INDEX_CACHE.clear()
    lerobot_read._FOOTER_CACHE.clear()


def _median_time(fn, repeats: int, setup=None) -> tuple[float, float]:
    """Median wall and CPU seconds of `repeats` calls (`setup` runs before each, untimed)."""
    wall, cpu = [], []
    for _ in range(repeats):
        if setup is not None:
            setup()
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - w0)
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), statistics.median(cpu)


def main(argv: list[str]) -> int:
    opts = {"episodes": 1000, "frames": 500, "dim": 14, "repeats": 5}
    for arg in argv:
        key, _, value = arg.partition("=")
        if key not in opts or not value.isdigit():
            print(f"usage: bench_logs.py [{' '.join(f'{k}={v}' for k, v in opts.items())}]", file=sys.stderr)
            return 2
        opts[key] = int(value)
    n, t, d, repeats = opts["episodes"], opts["frames"], opts["dim"], opts["repeats"]
    rng = np.random.default_rng(0)
    episodes = [
        {
            "observation.state": rng.standard_normal((t, d), dtype=np.float32),
            "action": rng.standard_normal((t, d), dtype=np.float32),
        }
        for _ in range(n)
    ]
    ds = from_arrays(episodes, fps=50)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "bench"
        t0 = time.perf_counter()
        write_dataset(root, ds)
        t_write = time.perf_counter() - t0
        size = sum(p.stat().st_size for p in root.rglob("*") if p.is_file())

        def full() -> None:
            got = read_dataset(root)
            assert len(got.episodes) == n

        # caches are cleared before each call, outside the timing (freeing the cached footer is not reading)
        t_full = _median_time(full, repeats, setup=_clear_caches)
        t_cold = _median_time(lambda: read_episode(root, n // 2), repeats, setup=_clear_caches)
        read_episode(root, 0)  # warm the metadata caches
        picks = iter(rng.integers(0, n, max(50, 20 * repeats)).tolist())
        t_warm = _median_time(lambda: read_episode(root, next(picks)), max(50, 20 * repeats))
        check = read_episode(root, 7)
        np.testing.assert_array_equal(check.data["action"], ds.episodes[7].data["action"])

    frames = n * t
    print(
        f"dataset: {n} episodes x {t} frames, {d}-D float32 state + action "
        f"({frames:,} frames, {size / 2**20:.1f} MiB on disk)"
    )
    print(f"{'':30}{'wall':>10}{'cpu':>10}   target      target/wall")
    print(f"{'write_dataset':30}{t_write * 1e3:8.1f}ms")
    rows = [
        ("read_dataset (whole)", t_full, 1.0),
        ("read_episode (cold metadata)", t_cold, None),
        ("read_episode (warm metadata)", t_warm, 5e-3),
    ]
    for label, (wall, cpu), target in rows:
        goal = f"< {target * 1e3:g} ms    {target / wall:6.1f}x" if target else ""
        print(f"{label:30}{wall * 1e3:8.2f}ms{cpu * 1e3:8.2f}ms   {goal}")
    print(
        f"whole read / one episode (warm): {t_full[0] / t_warm[0]:.0f}x wall for a dataset of {n} episodes; "
        f"{frames / t_full[0] / 1e6:.1f} M frames/s"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
