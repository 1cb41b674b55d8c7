"""bench.core.video: MP4 encoding (in the caller's thread and behind a bounded queue on a background thread) and
frame-accurate decoding, with real PyAV encoders; codec tolerance as stated in tests/video_frames.py."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest
from video_frames import assert_close_frames, frames

from bench.core.video import BackgroundMp4Writer, Mp4Writer, VideoError, decode_frames, probe


@pytest.mark.parametrize("codec,size", [("h264", (48, 64)), ("h264", (45, 61)), ("av1", (64, 64))])
def test_roundtrip_within_codec_tolerance(tmp_path, codec, size):
    want = frames(12, *size)
    with Mp4Writer(tmp_path / "v.mp4", fps=20, codec=codec) as w:
        w.write_many(want)
    info = probe(tmp_path / "v.mp4")
    odd = size[0] % 2 or size[1] % 2
    assert info["video.codec"] == codec and info["video.fps"] == 20
    assert (info["video.height"], info["video.width"]) == size
    assert info["video.pix_fmt"] == ("yuv444p" if odd else "yuv420p")
    got = decode_frames(tmp_path / "v.mp4", np.arange(12) / 20)
    assert_close_frames(got, want, codec)
    assert [p.name for p in tmp_path.iterdir()] == ["v.mp4"]  # no temporary file left


def test_decode_seeks_and_reorders(tmp_path):
    want = frames(30, 48, 64)
    with Mp4Writer(tmp_path / "v.mp4", fps=10, gop=5) as w:
        w.write_many(want)
    picks = np.array([21, 7, 22, 29])
    got = decode_frames(tmp_path / "v.mp4", picks / 10, shape=(48, 64, 3))
    assert_close_frames(got[[1, 0, 2, 3]], want[[7, 21, 22, 29]], "h264")


def test_decode_names_a_missing_time(tmp_path):
    with Mp4Writer(tmp_path / "v.mp4", fps=10) as w:
        w.write_many(frames(5, 16, 16))
    with pytest.raises(VideoError, match=r"no frame within 0.0001 s of t=0.550000"):
        decode_frames(tmp_path / "v.mp4", np.array([0.1, 0.55]))
    with pytest.raises(VideoError, match=r"no frame within .* of t=0.500000 s"):
        decode_frames(tmp_path / "v.mp4", np.array([0.5]))  # past the end
    (tmp_path / "bad.mp4").write_bytes(b"not a video")
    with pytest.raises(VideoError, match="bad.mp4: cannot decode"):
        decode_frames(tmp_path / "bad.mp4", np.array([0.0]))


def test_pad_odd_keeps_yuv420p_for_browsers(tmp_path):
    with Mp4Writer(tmp_path / "v.mp4", fps=10, pad_odd=True, gop=250) as w:
        w.write_many(frames(4, 45, 61))
    info = probe(tmp_path / "v.mp4")
    assert (info["video.height"], info["video.width"], info["video.pix_fmt"]) == (46, 62, "yuv420p")


def test_bad_arguments_are_one_line_errors(tmp_path):
    with pytest.raises(VideoError, match="codec is 'vp9'; valid: h264, av1"):
        Mp4Writer(tmp_path / "v.mp4", fps=10, codec="vp9")
    with pytest.raises(VideoError, match="fps is 12.5; expected a positive whole number"):
        Mp4Writer(tmp_path / "v.mp4", fps=12.5)
    with pytest.raises(VideoError, match="45x61: AV1 .* needs an even height and width"):
        Mp4Writer(tmp_path / "v.mp4", fps=10, codec="av1").write(frames(1, 45, 61)[0])
    w = Mp4Writer(tmp_path / "v.mp4", fps=10)
    w.write(frames(1, 16, 16)[0])
    with pytest.raises(VideoError, match=r"frame 1 is \(8, 16, 3\); the video's frames are \(16, 16, 3\)"):
        w.write(np.zeros((8, 16, 3), np.uint8))
    with pytest.raises(VideoError, match=r"frame 1 is \(16, 16, 3\) float64; expected \(H, W, 3\) uint8"):
        w.write(np.zeros((16, 16, 3)))
    w.abort()
    with pytest.raises(VideoError, match="no frames were written"):
        Mp4Writer(tmp_path / "e.mp4", fps=10).close()
    assert list(tmp_path.iterdir()) == []


def test_background_writer_bounded_queue_and_output(tmp_path):
    want = frames(40, 48, 48)
    w = BackgroundMp4Writer(tmp_path / "v.mp4", fps=10, queue_size=3)
    seen = []
    for f in want:
        w.write(f)
        seen.append(w._queue.qsize())  # frames waiting to be encoded
    assert max(seen) <= 3
    f = want[0].copy()
    assert w.close() == tmp_path / "v.mp4"
    assert_close_frames(decode_frames(tmp_path / "v.mp4", np.arange(40) / 10), want, "h264")
    np.testing.assert_array_equal(f, want[0])  # frames are copied, the caller may reuse its buffer


def test_background_writer_copies_reused_buffers(tmp_path):
    """A renderer may hand the same buffer every step: what is written is the frame at write time."""
    want = frames(10, 48, 48)
    buf = np.empty_like(want[0])
    with BackgroundMp4Writer(tmp_path / "v.mp4", fps=10, queue_size=16) as w:
        for f in want:
            buf[...] = f
            w.write(buf)
    assert_close_frames(decode_frames(tmp_path / "v.mp4", np.arange(10) / 10), want, "h264")


def test_background_writer_surfaces_encoder_errors(tmp_path):
    w = BackgroundMp4Writer(tmp_path / "v.mp4", fps=10, queue_size=2)
    w.write(frames(1, 16, 16)[0])
    w.write(np.zeros((8, 8, 3), np.uint8))  # accepted by the queue; the encoder thread fails on it
    with pytest.raises(VideoError, match=r"frame 1 is \(8, 8, 3\)"):
        for _ in range(200):  # raised by a later write (or close) once the thread has hit it
            w.write(frames(1, 16, 16)[0])
            time.sleep(0.005)
        w.close()
    with pytest.raises(VideoError):
        w.close()
    assert list(tmp_path.iterdir()) == []  # nothing under the name, no temporary file


def test_background_writer_abort_and_context_exit(tmp_path):
    with pytest.raises(RuntimeError, match="policy crashed"), BackgroundMp4Writer(tmp_path / "v.mp4", fps=10) as w:
        w.write(frames(1, 16, 16)[0])
        raise RuntimeError("policy crashed")
    assert list(tmp_path.iterdir()) == []
    threads = [t for t in threading.enumerate() if t.name.startswith("mp4-")]
    assert threads == []
