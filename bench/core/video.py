"""MP4 video with PyAV: an encoder, the same encoder on a background thread, and a frame-accurate decoder.

Three users share it: LeRobot v3 video features (`bench.logs.lerobot`, many episodes one after
another in one file), episode videos of `bench run video=N` (one file per episode, written
while the episode runs) and the readers of both.

- `Mp4Writer` encodes (H, W, 3) uint8 frames at a constant frame rate: frame k has
  presentation time k / fps exactly (stream time base 1/fps), which is what LeRobot's
  `from_timestamp + timestamp` lookup relies on. The file appears under its name only when
  `close()` succeeds (written to a hidden temporary sibling, then renamed).
- `BackgroundMp4Writer` runs an `Mp4Writer` on a thread behind a bounded queue, so the step
  loop only copies a frame into the queue; it blocks (back-pressure) when the encoder falls
  behind instead of growing memory, and an encoder failure is raised at the next `write`
  or at `close`, never lost.
- `decode_frames` returns the frames whose presentation times match given times (within a
  tolerance, LeRobot's 1e-4 s by default), seeking to the keyframe before the first one.

Codecs: `h264` (libx264; default) and `av1` (libsvtav1, LeRobot's default). Encoder defaults
favour random access and fidelity, as datasets need: a keyframe every `gop` frames (2, as
LeRobot), no B-frames, one encoder thread (these machines are shared). Pixel format:
yuv420p (what every player and LeRobot expect); H.264 frames with an odd width or height
use yuv444p, or are padded to even sizes with `pad_odd=True` for videos meant for a browser;
AV1 (4:2:0 only here) refuses odd sizes. Odd-sized 4:2:0 files exist (lerobot writes them), but
their colour is decoder-dependent: PyAV and torchcodec turn the same file into frames up to ~20
levels apart at colour edges, where even sizes decode identically. All of it is recorded by `probe`.
"""

from __future__ import annotations

import os
import queue
import threading
import uuid
from abc import ABC, abstractmethod
from fractions import Fraction
from pathlib import Path
from types import ModuleType, TracebackType
from typing import TYPE_CHECKING, TypedDict, TypeVar

import numpy as np
import numpy.typing as npt

from bench.core.errors import BenchError

if TYPE_CHECKING:
    from av.container import OutputContainer
    from av.video.stream import VideoStream
    from typing_extensions import Unpack  # typing's own from Python 3.11

Frame = npt.NDArray[np.uint8]  # (H, W, 3) RGB

CODECS = {"h264": "libx264", "av1": "libsvtav1"}
DEFAULT_CRF = {"h264": 20, "av1": 30}
TOLERANCE_S = 1e-4  # LeRobot's default `tolerance_s` between a requested time and a decoded frame's


class VideoError(BenchError):
    """A video that cannot be encoded or decoded: unknown codec, bad frames, unwritable or corrupt file."""


def _av() -> ModuleType:
    try:
        import av  # PyAV: loaded only when video is encoded or decoded
    except ImportError:  # pragma: no cover - av is a core dependency
        raise VideoError("video needs PyAV: pip install 'av<19' (av 19 needs numpy 2)") from None
    return av


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0] if text else type(exc).__name__


def _rate(fps: float) -> Fraction:
    if not np.isfinite(fps) or fps <= 0 or float(fps) != int(fps):
        raise VideoError(f"video fps is {fps!r}; expected a positive whole number of frames per second")
    return Fraction(int(fps), 1)


def check_codec(codec: str) -> None:
    """Raise `VideoError` unless `codec` is one of `CODECS` and this PyAV build can encode it."""
    if codec not in CODECS:
        raise VideoError(f"video codec is {codec!r}; valid: {', '.join(CODECS)}")
    try:
        _av().codec.Codec(CODECS[codec], "w")
    except Exception:
        raise VideoError(f"video codec {codec!r} ({CODECS[codec]}) is not available in this PyAV build") from None


def check_size(codec: str, height: int, width: int, pad_odd: bool = False) -> None:
    """Raise `VideoError` if frames of this size cannot be stored faithfully with `codec` (see the module doc)."""
    if codec == "av1" and (height % 2 or width % 2) and not pad_odd:
        raise VideoError(
            f"video frames are {height}x{width}: AV1 here is 4:2:0 only and needs an even height and "
            f"width (odd sizes decode differently in different decoders); use codec h264"
        )


_W = TypeVar("_W", bound="_Finishes")


class _Finishes(ABC):
    """`with writer:` closes the file on success and aborts it (nothing left behind) on an exception."""

    @abstractmethod
    def close(self) -> Path:
        """Finish the file and return its path."""

    @abstractmethod
    def abort(self) -> None:
        """Remove what was written."""

    def __enter__(self: _W) -> _W:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


class Mp4Writer(_Finishes):
    """Encode frames of one size into an MP4 file at a constant frame rate (synchronous).

    Args:
        path: the .mp4 file to write; its folder is created. Written to a temporary sibling and
            renamed on `close()`, so a failed or aborted write leaves no file under this name.
        fps: frames per second (a whole number; frame k is shown at k / fps seconds).
        codec: "h264" or "av1".
        crf: quality (lower is better; default 20 for H.264, 30 for AV1).
        gop: keyframe interval in frames (small = fast random access, larger files).
        pad_odd: pad an odd width/height by one replicated pixel (yuv420p stays playable in browsers)
            instead of switching H.264 to yuv444p.
        threads: encoder threads.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        fps: float,
        codec: str = "h264",
        crf: int | None = None,
        gop: int = 2,
        pad_odd: bool = False,
        threads: int = 1,
    ):
        check_codec(codec)
        self.path = Path(path)
        self.rate = _rate(fps)
        self.codec = codec
        self.crf = DEFAULT_CRF[codec] if crf is None else int(crf)
        self.gop = max(1, int(gop))
        self.pad_odd = bool(pad_odd)
        self.threads = max(1, int(threads))
        self.frames = 0
        self.shape: tuple[int, int, int] | None = None
        self.pix_fmt = "yuv420p"
        self._container: OutputContainer | None = None
        self._stream: VideoStream | None = None
        self._tmp = self.path.parent / f".{self.path.name}.{uuid.uuid4().hex[:8]}.tmp.mp4"
        self._closed = False

    def _open(self, frame: Frame) -> None:
        av = _av()
        height, width = frame.shape[:2]
        check_size(self.codec, height, width, self.pad_odd)
        odd = height % 2 or width % 2
        if odd and self.pad_odd:
            height, width = height + height % 2, width + width % 2
        elif odd and self.codec == "h264":
            self.pix_fmt = "yuv444p"
        options = {"crf": str(self.crf), "g": str(self.gop)}
        if self.codec == "h264":
            options.update({"bf": "0", "threads": str(self.threads), "preset": "veryfast"})
        else:
            options.update({"preset": "12", "svtav1-params": f"lp={self.threads}"})
            os.environ.setdefault("SVT_LOG", "1")  # SVT-AV1 prints its whole configuration to stderr otherwise
        self.path.parent.mkdir(parents=True, exist_ok=True)
        try:
            self._container = container = av.open(str(self._tmp), "w", format="mp4")
            self._stream = stream = container.add_stream(CODECS[self.codec], rate=self.rate, options=options)
            stream.width, stream.height = width, height
            stream.pix_fmt = self.pix_fmt
            stream.time_base = 1 / self.rate
        except Exception as exc:
            self._discard()
            raise VideoError(
                f"{self.path}: cannot start {self.codec} video {width}x{height}: {_first_line(exc)}"
            ) from None

    def write(self, frame: Frame) -> None:
        """Append one (H, W, 3) uint8 frame; every frame must have the first one's size."""
        if self._closed:
            raise VideoError(f"{self.path}: write after close")
        arr = np.asarray(frame)
        if arr.dtype != np.uint8 or arr.ndim != 3 or arr.shape[2] != 3:
            raise VideoError(f"{self.path}: frame {self.frames} is {arr.shape} {arr.dtype}; expected (H, W, 3) uint8")
        if self.shape is None:
            self.shape = (arr.shape[0], arr.shape[1], 3)
            self._open(arr)
        elif arr.shape != self.shape:
            raise VideoError(f"{self.path}: frame {self.frames} is {arr.shape}; the video's frames are {self.shape}")
        if self.pad_odd and (arr.shape[0] % 2 or arr.shape[1] % 2):
            arr = np.pad(arr, ((0, arr.shape[0] % 2), (0, arr.shape[1] % 2), (0, 0)), mode="edge")
        av = _av()
        container, stream = self._container, self._stream
        if container is None or stream is None:  # its first frame could not start the file
            raise VideoError(f"{self.path}: cannot encode frame {self.frames}: the video could not be started")
        try:
            vf = av.VideoFrame.from_ndarray(np.ascontiguousarray(arr), format="rgb24")
            vf.pts = self.frames  # in the codec's time base 1/fps (the muxer may change the stream's)
            for packet in stream.encode(vf):
                container.mux(packet)
        except Exception as exc:
            self.abort()
            raise VideoError(f"{self.path}: cannot encode frame {self.frames}: {_first_line(exc)}") from None
        self.frames += 1

    def write_many(self, frames: npt.NDArray[np.uint8]) -> None:
        """Append (T, H, W, 3) uint8 frames."""
        for frame in frames:
            self.write(frame)

    @property
    def bytes_written(self) -> int:
        """Bytes in the file so far (the index is added at close)."""
        try:
            return self._tmp.stat().st_size
        except OSError:
            return 0

    def close(self) -> Path:
        """Flush the encoder, finish the file and move it into place; returns its path."""
        if self._closed:
            return self.path
        container, stream = self._container, self._stream
        if container is None or stream is None:
            self._closed = True
            raise VideoError(f"{self.path}: no frames were written")
        try:
            for packet in stream.encode():
                container.mux(packet)
            container.close()
            self._container = None
            os.replace(self._tmp, self.path)
        except Exception as exc:
            self.abort()
            raise VideoError(f"{self.path}: cannot finish the video: {_first_line(exc)}") from None
        self._closed = True
        return self.path

    def abort(self) -> None:
        """Stop without producing a file (what was encoded is deleted)."""
        self._closed = True
        self._discard()

    def _discard(self) -> None:
        if self._container is not None:
            try:
                self._container.close()
            except Exception:  # already failing: the file is deleted below
                pass
            self._container = None
        self._tmp.unlink(missing_ok=True)


class Mp4Options(TypedDict, total=False):
    """`Mp4Writer`'s options by keyword (what `BackgroundMp4Writer` passes on)."""

    codec: str
    crf: int | None
    gop: int
    pad_odd: bool
    threads: int


class BackgroundMp4Writer(_Finishes):
    """An `Mp4Writer` fed through a bounded queue by a background thread (keeps encoding off the step loop).

    `write(frame)` copies the frame into the queue and returns; when `queue_size` frames are
    waiting it blocks until the encoder catches up (memory stays bounded). PyAV releases the GIL
    while it converts and encodes, so the caller's thread keeps running meanwhile. An error in the
    encoder thread is raised by the next `write` or by `close` as a `VideoError`. `close()` waits
    for every queued frame and returns the path; `abort()` drops the queue and the file.

    Args are those of `Mp4Writer` (its options by keyword: codec, crf, gop, pad_odd, threads),
    plus `queue_size` (frames waiting at most).
    """

    def __init__(
        self, path: str | os.PathLike[str], fps: float, *, queue_size: int = 64, **options: Unpack[Mp4Options]
    ):
        self._writer = Mp4Writer(path, fps, **options)
        self.path = self._writer.path
        self._queue: queue.Queue[Frame | None] = queue.Queue(maxsize=max(1, int(queue_size)))
        self._error: BaseException | None = None
        self._aborted = threading.Event()
        self._done = False
        self._thread = threading.Thread(target=self._run, name=f"mp4-{self.path.name}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            item = self._queue.get()
            if item is None or self._aborted.is_set():  # None: stop
                break
            try:
                self._writer.write(item)
            except BaseException as exc:  # handed to the caller's thread
                self._error = exc
                self._aborted.set()
                break
        if self._aborted.is_set():
            self._writer.abort()
            while not self._queue.empty():  # unblock a producer waiting on a full queue
                self._queue.get_nowait()
            return
        try:
            self._writer.close()
        except BaseException as exc:
            self._error = exc

    def _raise(self) -> None:
        if self._error is not None:
            err, self._error = self._error, None
            if isinstance(err, VideoError):
                raise err
            raise VideoError(f"{self.path}: video encoder failed: {_first_line(err)}") from err

    def _put(self, item: Frame | None) -> None:
        while True:
            self._raise()
            if not self._thread.is_alive():
                raise VideoError(f"{self.path}: the video encoder has stopped")
            try:
                self._queue.put(item, timeout=0.1)
                return
            except queue.Full:
                continue

    def write(self, frame: Frame) -> None:
        """Queue a copy of one (H, W, 3) uint8 frame (blocks only while the queue is full)."""
        if self._done:
            raise VideoError(f"{self.path}: write after close")
        self._put(np.array(frame, dtype=np.uint8, copy=True))

    def close(self, timeout: float | None = None) -> Path:
        """Encode what is queued, finish the file and return its path (raises the encoder's error)."""
        if not self._done:
            self._done = True
            if self._thread.is_alive():
                self._put(None)
        self._thread.join(timeout)
        if self._thread.is_alive():
            raise VideoError(f"{self.path}: the video encoder did not finish within {timeout} s")
        self._raise()
        if not self.path.exists():
            raise VideoError(f"{self.path}: the video was not written")
        return self.path

    def abort(self) -> None:
        """Drop queued frames and the partial file; waits for the thread to stop."""
        self._done = True
        self._aborted.set()
        try:
            self._queue.put_nowait(None)
        except queue.Full:
            pass
        self._thread.join()
        self._error = None


def probe(path: str | os.PathLike[str]) -> dict[str, object]:
    """The `info` LeRobot stores for a video feature: size, codec, pixel format, fps, channels, audio."""
    av = _av()
    try:
        with av.open(str(path), "r") as container:
            if not container.streams.video:
                raise VideoError(f"{path}: has no video stream")
            stream = container.streams.video[0]
            pix_fmt = stream.codec_context.pix_fmt or stream.format.name
            info = {
                "video.height": int(stream.height),
                "video.width": int(stream.width),
                "video.codec": stream.codec_context.codec.canonical_name if stream.codec_context.codec else None,
                "video.pix_fmt": pix_fmt,
                "video.is_depth_map": False,
                "video.fps": int(stream.base_rate) if stream.base_rate else None,
                "video.channels": 4 if pix_fmt and ("rgba" in pix_fmt or "yuva" in pix_fmt) else 3,
                "has_audio": bool(container.streams.audio),
            }
    except VideoError:
        raise
    except Exception as exc:
        raise VideoError(f"{path}: not a readable video: {_first_line(exc)}") from None
    return info


def decode_frames(
    path: str | os.PathLike[str],
    times: npt.ArrayLike,
    shape: tuple[int, ...] | None = None,
    tolerance_s: float = TOLERANCE_S,
) -> npt.NDArray[np.uint8]:
    """Decode the frames shown at `times` (seconds from the start of the file) as (N, H, W, 3) uint8.

    Seeks to the keyframe before the earliest time and decodes forward once; each requested time
    takes the frame whose presentation time is within `tolerance_s` of it. Raises `VideoError`
    naming the time when no frame is that close (a file shorter than its index says, or frames
    placed at other times), or when a frame's size differs from `shape`.
    """
    av = _av()
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    order = np.argsort(times, kind="stable")
    wanted = times[order]
    out: npt.NDArray[np.uint8] | None = None
    if shape is not None:
        out = np.empty((len(times),) + tuple(shape), dtype=np.uint8)
    if not len(times):
        return out if out is not None else np.empty((0, 0, 0, 3), np.uint8)
    k = 0
    try:
        with av.open(str(path), "r") as container:
            if not container.streams.video:
                raise VideoError(f"{path}: has no video stream")
            stream = container.streams.video[0]
            tb = stream.time_base
            if wanted[0] > tolerance_s and tb:
                container.seek(
                    max(0, int(np.floor((wanted[0] - tolerance_s) / float(tb)))),
                    stream=stream,
                    backward=True,
                    any_frame=False,
                )
            for frame in container.decode(stream):
                if frame.pts is None:
                    continue
                t = float(frame.pts * tb)
                if t < wanted[k] - tolerance_s:
                    continue
                if abs(t - wanted[k]) > tolerance_s:
                    break  # the stream went past a requested time without a frame there
                img = frame.to_ndarray(format="rgb24")
                if out is None:
                    out = np.empty((len(times),) + img.shape, dtype=np.uint8)
                if img.shape != out.shape[1:]:
                    raise VideoError(f"{path}: frame at {t:.4f} s is {img.shape}, expected {out.shape[1:]}")
                while k < len(wanted) and abs(t - wanted[k]) <= tolerance_s:
                    out[order[k]] = img
                    k += 1
                if k == len(wanted):
                    break
    except VideoError:
        raise
    except Exception as exc:
        raise VideoError(f"{path}: cannot decode: {_first_line(exc)}") from None
    if k < len(wanted):
        raise VideoError(
            f"{path}: no frame within {tolerance_s:g} s of t={wanted[k]:.6f} s (file shorter than its "
            f"index, or frames at other times)"
        )
    assert out is not None
    return out
