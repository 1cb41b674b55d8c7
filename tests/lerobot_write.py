"""Write a small LeRobot v3 dataset with lerobot itself, camera streams as video (run with the side venv's python).

    python tests/lerobot_write.py ROOT OUT_NPZ [VCODEC]

Uses lerobot's own recording API (`LeRobotDataset.create`, `add_frame`, `save_episode`, `finalize`), so the
mp4 files, the `videos/...` columns of the episodes table and the info.json entries are exactly what
lerobot writes; VCODEC is lerobot's `vcodec` (default: its own default, libsvtav1 = AV1). Three episodes of
different lengths and two tasks; two cameras of different sizes, each frame a smooth scene that moves
with time (`video_frames.frame`: noise would not survive a lossy codec), plus a state vector, an action and a scalar reward.
OUT_NPZ gets the frames that were handed to lerobot, stacked in frame order, so the test can compare bench's
decoding with them. No bench import: this runs where bench is not installed; `frame` is also used by the
interop test on bench's side (from tests/video_frames.py; lerobot is imported only by `main`).
"""

import os
import sys

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import numpy as np  # noqa: E402
from video_frames import frame  # noqa: E402  (tests/ is on sys.path when run as a script)

FPS = 10
CAMERAS = {"observation.images.front": (96, 128), "observation.images.wrist": (64, 64)}
LENGTHS = (7, 12, 9)
TASKS = ("open the drawer", "close the drawer", "open the drawer")


def main(root: str, out: str, vcodec: str | None = None) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    features = {
        "observation.state": {"dtype": "float32", "shape": (3,), "names": ["x", "y", "z"]},
        "action": {"dtype": "float32", "shape": (2,), "names": ["a0", "a1"]},
        "next.reward": {"dtype": "float32", "shape": (1,), "names": None},
    }
    for key, (h, w) in CAMERAS.items():
        features[key] = {"dtype": "video", "shape": (h, w, 3), "names": ["height", "width", "channels"]}
    kwargs = {} if vcodec is None else {"vcodec": vcodec}
    ds = LeRobotDataset.create(
        "bench/lerobot-video", fps=FPS, features=features, root=root, robot_type="toy", use_videos=True, **kwargs
    )
    given: dict[str, list] = {k: [] for k in (*CAMERAS, "observation.state", "action", "next.reward")}
    rng = np.random.default_rng(0)
    for _e, (length, task) in enumerate(zip(LENGTHS, TASKS)):
        for t in range(length):
            row = {
                "observation.state": rng.standard_normal(3).astype(np.float32),
                "action": rng.standard_normal(2).astype(np.float32),
                "next.reward": np.float32([t / length]),
                "task": task,
            }
            for c, (key, (h, w)) in enumerate(CAMERAS.items()):
                row[key] = frame(h, w, len(given["action"]), c)  # scene time = frame's index in the dataset
            for key in given:
                given[key].append(row[key])
            ds.add_frame(row)
        ds.save_episode()
    ds.finalize()
    np.savez(out, **{k: np.stack(v) for k, v in given.items()})


if __name__ == "__main__":
    if not 3 <= len(sys.argv) <= 4:
        print("usage: python tests/lerobot_write.py ROOT OUT_NPZ [VCODEC]", file=sys.stderr)
        sys.exit(2)
    main(*sys.argv[1:])
