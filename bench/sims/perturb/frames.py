"""Image-noise axes, one row each: what a camera sensor and its link do to the frames the policy sees.

Each row wraps the env for an episode (`NoisyFrames`): every `rgb.*` image of every observation goes
through one corruption drawn from the episode's own generator, so the episode video (taken from the
observations) shows what the policy saw. State observations are untouched.

    image_noise   Gaussian read noise, std as a share of full scale (0..1)
    shot_noise    photon shot noise: counts with Poisson variance whose std at full white is this share of full scale
    salt_pepper   share of pixels set to black or white
    motion_blur   length in pixels of a linear blur at an angle drawn per episode
    jpeg_quality  JPEG quality 1..100 (OpenCV's encoder); 100 = frames not compressed (nominal)
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import partial

import numpy as np

from bench.protocols import RGB, EnvAdapter, Obs
from bench.protocols.env import AdapterWrapper
from bench.sims.perturb.axis import RGB_IMAGES, Axis, Params, Wrap

Corrupt = Callable[[np.ndarray, np.random.Generator], np.ndarray]  # (H, W, 3) uint8 -> (H, W, 3) uint8


class NoisyFrames(AdapterWrapper):
    """The env whose camera images pass through `corrupt` (with the episode's generator) at every observation."""

    def __init__(self, env: EnvAdapter, rng: np.random.Generator, corrupt: Corrupt):
        super().__init__(env)
        self.rng, self.corrupt = rng, corrupt

    def _obs(self, obs: Obs) -> Obs:
        return {k: self.corrupt(np.asarray(v), self.rng) if k.startswith(RGB) else v for k, v in obs.items()}

    def reset(self, seed: int) -> Obs:
        return self._obs(self.inner.reset(seed))

    def edit_start(self, edit: Callable[[], None]) -> Obs:
        return self._obs(super().edit_start(edit))  # the edited start's images corrupted too

    def step(self, action: np.ndarray) -> tuple[Obs, float, bool, bool, dict[str, object]]:
        obs, reward, terminated, truncated, info = self.inner.step(action)
        return self._obs(obs), reward, terminated, truncated, info


def _to_uint8(x: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(x), 0, 255).astype(np.uint8)


def _gaussian(level: float) -> Corrupt:
    def corrupt(img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        noise = rng.standard_normal(img.shape, dtype=np.float32)
        return _to_uint8(img + noise * np.float32(255.0 * level))

    return corrupt


def _shot(level: float) -> Corrupt:
    """Photon shot noise with Poisson statistics at 1/level^2 photons at full white: each pixel's count has
    variance equal to its mean. Drawn in the normal approximation (exact mean and variance; the count of a
    pixel brighter than 1/10 of white at level 0.1 is over 10 photons, where the two agree), which costs a
    third of an exact Poisson draw per frame."""

    def corrupt(img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        x = img.astype(np.float32)
        noise = rng.standard_normal(img.shape, dtype=np.float32)
        return _to_uint8(x + np.sqrt(x * np.float32(255.0)) * np.float32(level) * noise)

    return corrupt


def _salt_pepper(level: float) -> Corrupt:
    def corrupt(img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        out = img.copy()
        hit = rng.random(img.shape[:2]) < level
        out[hit] = np.where(rng.random(int(hit.sum())) < 0.5, 0, 255)[:, None].astype(np.uint8)
        return out

    return corrupt


def _blur_kernel(length: int, degrees: float) -> np.ndarray:
    """A normalised line of `length` pixels at `degrees`, for cv2.filter2D."""
    k = np.zeros((length, length), dtype=np.float32)
    c, a = (length - 1) / 2.0, math.radians(degrees)
    for t in np.linspace(-c, c, 4 * length):
        k[int(round(c + t * math.sin(a))), int(round(c + t * math.cos(a)))] = 1.0
    return k / k.sum()


def _motion_blur(length: int, degrees: float) -> Corrupt:
    kernel = _blur_kernel(length, degrees)

    def corrupt(img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        import cv2  # OpenCV (a core dependency) costs ~0.2 s to import: loaded only when frames are blurred

        return np.asarray(cv2.filter2D(img, -1, kernel, borderType=cv2.BORDER_REFLECT))

    return corrupt


def _jpeg(quality: int) -> Corrupt:
    def corrupt(img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        import cv2  # OpenCV (a core dependency) costs ~0.2 s to import: loaded only when frames are encoded

        ok, buf = cv2.imencode(".jpg", img[..., ::-1], [int(cv2.IMWRITE_JPEG_QUALITY), int(quality)])
        if not ok:
            raise RuntimeError(f"OpenCV could not JPEG-encode a {img.shape} frame")
        return np.ascontiguousarray(cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1])

    return corrupt


def _wrap(make: Callable[[float], Corrupt], neutral: float) -> Wrap:
    def wrap(env: EnvAdapter, rng: np.random.Generator, level: float) -> tuple[EnvAdapter, Params]:
        if float(level) == neutral:
            return env, {}
        return NoisyFrames(env, rng, make(level)), {}

    return wrap


def _wrap_blur(env: EnvAdapter, rng: np.random.Generator, level: float) -> tuple[EnvAdapter, Params]:
    degrees = float(rng.uniform(0.0, 180.0))
    if int(level) <= 1:
        return env, {}
    return NoisyFrames(env, rng, _motion_blur(int(level), degrees)), {"motion_blur.angle_deg": round(degrees, 3)}


_frame_axis = partial(Axis, kind="visual", sees=RGB_IMAGES, nominal=0.0, maximum=1.0)  # an image-noise axis


def _noise_row(name: str, unit: str, short: str, doc: str, corrupt: Callable[[float], Corrupt]) -> Axis:
    """A frame axis whose level (a share, 0..1; 0 = none) sets one corruption of every image."""
    return _frame_axis(name, unit=unit, short=short, doc=doc, wrap=_wrap(lambda v: corrupt(float(v)), 0.0))


ROWS: tuple[Axis, ...] = (
    _noise_row(
        "image_noise",
        "std as a share of full scale",
        "Gaussian read noise on images",
        "Gaussian noise added to every pixel of every camera image the policy sees, then clipped",
        _gaussian,
    ),
    _noise_row(
        "shot_noise",
        "std at full white as a share of full scale",
        "photon shot noise on images",
        "Poisson photon noise: each pixel a count of photons (1/level^2 at full white), so darker pixels "
        "are relatively noisier",
        _shot,
    ),
    _noise_row(
        "salt_pepper",
        "share of pixels",
        "salt-and-pepper pixels",
        "this share of each image's pixels set to black or white (dead and hot pixels, bit errors)",
        _salt_pepper,
    ),
    _frame_axis(
        "motion_blur",
        unit="pixels",
        short="motion blur of images",
        doc="every image blurred along a line this many pixels long, at an angle drawn per episode (0 and 1: none)",
        integer=True,
        wrap=_wrap_blur,
        maximum=64.0,
    ),
    _frame_axis(
        "jpeg_quality",
        unit="JPEG quality 1..100",
        short="JPEG compression of images",
        doc="every image JPEG-encoded and decoded at this quality (OpenCV); 100 = not compressed (nominal)",
        minimum=1.0,
        integer=True,
        wrap=_wrap(lambda v: _jpeg(int(v)), 100.0),
        nominal=100.0,
        maximum=100.0,
    ),
)
