"""Camera frames for the video tests, and the codec tolerance they are held to (numpy only: the lerobot side
venv imports it too, from tests/lerobot_write.py).

Tolerance, stated once: a lossy codec keeps each frame of these smooth synthetic scenes within a mean absolute
error of `MAE[codec]` levels of 255 (measured on 45x61 .. 96x128 frames: H.264 at bench's default crf 20,
4:2:0, 2.3-4.1; AV1 at lerobot's crf 30, 4.5-6.8), and a decoded frame must also be closer to the frame written
at its own index than to any other frame (the scene moves every frame), so a frame off by one fails even where
the error bound alone would pass.
"""

from __future__ import annotations

import numpy as np

MAE = {"h264": 5.0, "av1": 8.0}


def frame(height: int, width: int, t: int, camera: int = 0) -> np.ndarray:
    """A smooth RGB scene (gradients and a soft-edged disc that moves with t) that a lossy codec keeps
    within a few levels; sharp coloured edges would be smeared by 4:2:0 chroma subsampling."""
    y, x = np.mgrid[0:height, 0:width].astype(np.float64)
    cx, cy = (0.2 + 0.11 * t) * width % width, (0.5 + 0.1 * camera) * height
    radius = 0.25 * min(height, width)
    alpha = np.clip((radius - np.hypot(x - cx, y - cy)) / (0.15 * radius + 1), 0, 1)[..., None]
    background = np.stack([255 * x / width, 255 * y / height, np.full_like(x, 20.0 + (8 * t) % 230)], axis=-1)
    disc = np.array([230.0, 40.0 + 20 * camera, 60.0])
    return np.rint(background * (1 - alpha) + disc * alpha).astype(np.uint8)


def frames(n: int, height: int, width: int, camera: int = 0, start: int = 0) -> np.ndarray:
    """(n, H, W, 3) uint8: `frame` at t = start .. start + n - 1."""
    return np.stack([frame(height, width, start + t, camera) for t in range(n)])


def assert_close_frames(got: np.ndarray, want: np.ndarray, codec: str, what: str = "") -> None:
    """`got` decodes `want` within the codec's tolerance, frame by frame and in the right order."""
    assert got.shape == want.shape and got.dtype == np.uint8, (what, got.shape, got.dtype, want.shape)
    n = len(want)
    err = np.abs(got.astype(np.float64) - want).reshape(n, -1).mean(axis=1)
    assert err.max() <= MAE[codec], f"{what}: mean absolute error per frame up to {err.max():.2f} > {MAE[codec]}"
    if n > 1:
        cross = np.abs(got[:, None].astype(np.float64) - want[None]).reshape(n, n, -1).mean(axis=-1)
        nearest = cross.argmin(axis=1)
        assert np.array_equal(nearest, np.arange(n)), f"{what}: decoded frames match written frames {nearest.tolist()}"
