"""Load a LeRobot v3 dataset with lerobot itself and dump what it read (run with the side venv's python).

    python tests/lerobot_load.py ROOT OUT_PREFIX [EPISODE]

Writes OUT_PREFIX.npz (every feature of every frame, stacked in frame order; camera frames as lerobot
returns them: float32 C x H x W in [0, 1]) and OUT_PREFIX.json (metadata lerobot read, the task string of
every frame, and, when EPISODE is given, the global indices lerobot returns for that episode alone).
No bench import: this runs where bench is not installed. Used by tests/test_lerobot_interop.py.
"""

import json
import os
import sys

os.environ.setdefault("HF_HUB_OFFLINE", "1")

import numpy as np  # noqa: E402
from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: E402


def main(root: str, out: str, episode: str | None = None) -> None:
    if not os.path.isfile(os.path.join(root, "meta", "info.json")):  # else lerobot would go to the hub
        print(f"error: {root}: not a LeRobot dataset folder (meta/info.json is missing)", file=sys.stderr)
        sys.exit(2)
    ds = LeRobotDataset("bench/interop", root=root)
    frames = [ds[i] for i in range(len(ds))]
    arrays, tasks = {}, []
    for key in frames[0]:
        if key == "task":
            tasks = [f["task"] for f in frames]
        else:
            arrays[key] = np.stack([np.asarray(f[key]) for f in frames])
    np.savez(out + ".npz", **arrays)
    meta = ds.meta
    doc = {
        "lerobot_len": len(ds),
        "num_episodes": ds.num_episodes,
        "fps": ds.fps,
        "total_episodes": meta.total_episodes,
        "total_frames": meta.total_frames,
        "total_tasks": meta.total_tasks,
        "robot_type": meta.robot_type,
        "features": {k: {"dtype": v["dtype"], "shape": list(v["shape"])} for k, v in meta.features.items()},
        "tasks_table": [str(t) for t in meta.tasks.index],
        "episode_lengths": [int(x) for x in meta.episodes["length"]],
        "frame_tasks": tasks,
    }
    if episode is not None:
        sub = LeRobotDataset("bench/interop", root=root, episodes=[int(episode)])
        doc["episode_subset"] = {
            "episode": int(episode),
            "index": [int(sub[i]["index"]) for i in range(len(sub))],
            "episode_index": sorted({int(sub[i]["episode_index"]) for i in range(len(sub))}),
        }
    with open(out + ".json", "w") as f:
        json.dump(doc, f)


if __name__ == "__main__":
    if not 3 <= len(sys.argv) <= 4:
        print("usage: python tests/lerobot_load.py ROOT OUT_PREFIX [EPISODE]", file=sys.stderr)
        sys.exit(2)
    main(*sys.argv[1:])
