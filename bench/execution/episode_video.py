"""`bench run video=N`: an MP4 of the first N episodes of every cell and condition.

The frames are what the env's cameras see (`env.mujoco.cameras`, a `bench.sims.camera.CameraRig`):
the policy's own camera images side by side when it observes images (`obs=rgb|state+rgb`, no
extra rendering), else the suite's first camera (a front view), rendered for the video only.
Visual perturbations show, since they act on the same rig. Frames are encoded by a
`BackgroundMp4Writer` (H.264, yuv420p so browsers play it), off the step loop's critical path;
a video that cannot be written is reported in the episode record's `extras["video"]`, never
fails the episode.

Files: RUN_DIR/videos/<job id made safe>.mp4 (`video_path`); the HTML report embeds them next
to their cell (`bench.board.report.page`).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from bench.core.errors import ConfigError
from bench.core.video import BackgroundMp4Writer
from bench.protocols import RGB, Cell, EnvAdapter, Obs, Suite
from bench.protocols.suite import Job
from bench.sims.camera import check_renderer

VIDEO_DIR = "videos"


def video_path(run_dir: str | Path, job_id: str) -> Path:
    """Where the video of job `job_id` goes (the job id made a plain file name)."""
    safe = job_id.replace("/", "__").replace("|", "--").replace("=", "-").replace("~", "_")
    return Path(run_dir) / VIDEO_DIR / f"{safe}.mp4"


class EpisodeVideo:
    """The video of one episode: `frame(obs)` after reset and after every step, then `close()`."""

    def __init__(self, path: Path, env: EnvAdapter, obs_keys: list[str]):
        self.path = path
        if env.mujoco is None:  # check_run refused the run before any episode
            raise ConfigError(f"video: env {env.backend} has no MuJoCo cameras")
        self.rig = env.mujoco.cameras
        self.keys = [k for k in obs_keys if k.startswith(RGB)]
        fps = float(env.fps) if env.fps and env.fps > 0 else 20.0
        self.fps = max(1, round(fps))
        # crf 23 and one keyframe a second: a file to watch, not a dataset to seek in
        self.writer = BackgroundMp4Writer(path, fps=self.fps, crf=23, gop=self.fps, pad_odd=True, queue_size=32)
        self.frames = 0
        self.error: str | None = None

    def frame(self, obs: Obs) -> None:
        """Add the frame of the current state (the observation's images, or a render of the first camera)."""
        if self.error is not None:
            return
        try:
            if self.keys:
                images = [np.asarray(obs[k]) for k in self.keys]
                img = images[0] if len(images) == 1 else _side_by_side(images)
            else:
                img = self.rig.render_one(self.rig.cameras[0])
            self.writer.write(img)
            self.frames += 1
        except Exception as exc:  # the video is a by-product: the episode goes on without it
            self.error = f"{type(exc).__name__}: {exc}"
            self.writer.abort()

    def close(self, run_dir: str | Path) -> dict[str, object]:
        """Finish the file; what the episode record keeps under `extras["video"]`."""
        if self.error is None:
            try:
                self.writer.close()
            except Exception as exc:
                self.error = f"{type(exc).__name__}: {exc}"
        if self.error is not None:
            return {"error": self.error}
        return {"path": str(self.path.relative_to(run_dir)), "frames": self.frames, "fps": self.fps}


def _side_by_side(images: list[np.ndarray]) -> np.ndarray:
    height = max(i.shape[0] for i in images)
    padded = [np.pad(i, ((0, height - i.shape[0]), (0, 0), (0, 0))) for i in images]
    return np.concatenate(padded, axis=1)


def start(run_dir: str | None, episodes: int, job: Job, env: EnvAdapter) -> EpisodeVideo | None:
    """The video of `job` when the run asks for one (`video=N`, job among the first N episodes) and the env
    has cameras; else None."""
    if not run_dir or job.episode >= episodes or env.mujoco is None or env.mujoco.cameras is None:
        return None
    return EpisodeVideo(video_path(run_dir, job.job_id), env, list(env.obs_spec))


def check_run(suite: Suite, cells: Sequence[Cell], horizon: int) -> None:
    """Before a `video=N` run writes anything: a renderer can start, and the first cell's env has cameras."""
    check_renderer()
    if not cells:
        return
    env = suite.make_env(cells[0], horizon)
    try:
        if env.mujoco is None or env.mujoco.cameras is None:
            raise ConfigError(
                f"video: {cells[0].key} ({env.backend}) has no camera to film; videos need a MuJoCo "
                f"suite whose model has a camera"
            )
    finally:
        env.close()
