"""The bytes on the wire: openpi's msgpack-numpy encoding, checked on the way in.

A message is one binary websocket frame holding a msgpack map. NumPy arrays travel as
openpi's `msgpack_numpy` writes them (so `openpi-client` and bench interoperate both ways):

    ndarray     {b"__ndarray__": True, b"data": <raw bytes, C order>, b"dtype": "<f4", b"shape": [T, A]}
    np scalar   {b"__npgeneric__": True, b"data": <python scalar>, b"dtype": "<f4"}

Nothing is ever unpickled: decoding builds arrays from raw bytes with a whitelisted dtype
(bool, integers, floats, fixed-width unicode), checks that the byte count fits the shape,
and refuses everything else with a `WireError` naming what was wrong. A server reports a
failure as a *text* frame holding one line (openpi's convention: its client raises on str).

The protocol on top (openpi's websocket policy server, plus one optional extension):
    1. on connect the server sends a metadata map (free-form; a bench server puts
       `{"bench": {"protocol": "bench.remote/1", ...}}` in it);
    2. the client sends an observation map, the server answers `{"actions": (T, A) array, ...}`
       (openpi servers add `server_timing: {infer_ms}`; so does bench's);
    3. extension, only towards servers whose metadata announce `bench.remote/1`: a map with the
       single key `__bench__` is a control request (`op`: "reset" at each episode start, "check"
       before a run); the answer is `{"__bench__": {"ok": True, ...}}`.
"""

from __future__ import annotations

import math
from typing import Any

import msgpack
import numpy as np

PROTOCOL = "bench.remote/1"
CONTROL = "__bench__"  # key of a control request / answer (never an observation key)
ACTIONS = "actions"  # key of the action chunk in an answer (openpi's)
ALLOWED_KINDS = frozenset("biufU")  # bool, int, uint, float, unicode: plain bytes, nothing executable
MAX_DIMS = 8


# A message: a decoded msgpack map (str keys; numbers, strings, arrays, lists and maps as values). What a
# value holds is the protocol's to say (an observation, `actions`, a control body), so values stay untyped here.
Message = dict[str, Any]


class WireError(ValueError):
    """A message that is not msgpack, or not what the protocol allows (one line: what and why)."""


def _encode_default(obj: object) -> object:
    if isinstance(obj, np.ndarray):
        if obj.dtype.kind not in ALLOWED_KINDS:
            raise WireError(f"cannot send an array of dtype {obj.dtype} (allowed kinds: bool, int, uint, float, str)")
        return {b"__ndarray__": True, b"data": obj.tobytes(), b"dtype": obj.dtype.str, b"shape": list(obj.shape)}
    if isinstance(obj, np.generic):
        if obj.dtype.kind not in ALLOWED_KINDS:
            raise WireError(f"cannot send a scalar of dtype {obj.dtype}")
        return {b"__npgeneric__": True, b"data": obj.item(), b"dtype": obj.dtype.str}
    if isinstance(obj, (tuple, set, frozenset)):
        return list(obj)
    raise WireError(f"cannot send a {type(obj).__name__} (send numpy arrays, numbers, strings, lists and maps)")


def encode(message: Message) -> bytes:
    """A msgpack frame of `message` (maps with str keys; numpy arrays and scalars as openpi encodes them)."""
    try:
        return msgpack.packb(message, default=_encode_default, use_bin_type=True)
    except WireError:
        raise
    except (TypeError, ValueError, OverflowError) as exc:
        raise WireError(f"cannot encode the message: {exc}") from None


def _dtype(value: object) -> np.dtype:
    if not isinstance(value, (str, bytes)):
        raise WireError(f"array dtype must be a string like '<f4', got {type(value).__name__}")
    try:
        dt = np.dtype(value.decode() if isinstance(value, bytes) else value)
    except (TypeError, ValueError, UnicodeDecodeError):
        raise WireError(f"array dtype {value!r} is not a numpy dtype string") from None
    if dt.kind not in ALLOWED_KINDS or dt.hasobject or dt.fields is not None or dt.subdtype is not None:
        raise WireError(f"array dtype {dt} is not allowed (allowed kinds: bool, int, uint, float, str)")
    return dt


def _array(obj: dict) -> np.ndarray:
    dt = _dtype(obj.get(b"dtype"))
    shape, data = obj.get(b"shape"), obj.get(b"data")
    if (
        not isinstance(shape, (list, tuple))
        or len(shape) > MAX_DIMS
        or not all(isinstance(n, int) and not isinstance(n, bool) and n >= 0 for n in shape)
    ):
        raise WireError(f"array shape must be a list of at most {MAX_DIMS} non-negative integers, got {shape!r}")
    if not isinstance(data, bytes):
        raise WireError(f"array data must be bytes, got {type(data).__name__}")
    want = math.prod(shape) * dt.itemsize
    if len(data) != want:
        raise WireError(f"array of shape {list(shape)} and dtype {dt} needs {want} bytes, got {len(data)}")
    # a copy: writable like an in-process observation, and independent of the frame's buffer
    return np.frombuffer(data, dtype=dt).reshape(shape).copy()


def _decode_hook(obj: dict) -> object:
    if b"__ndarray__" in obj:
        return _array(obj)
    if b"__npgeneric__" in obj:
        dt = _dtype(obj.get(b"dtype"))
        value = obj.get(b"data")
        if isinstance(value, (dict, list, bytes)) or value is None:
            raise WireError(f"numpy scalar data must be a number or string, got {type(value).__name__}")
        try:
            return dt.type(value)
        except (TypeError, ValueError, OverflowError) as exc:
            raise WireError(f"numpy scalar {value!r} does not fit dtype {dt}: {exc}") from None
    return obj


def decode(frame: object, what: str = "message") -> Message:
    """The map in a binary frame, arrays rebuilt; WireError for a text frame, non-msgpack bytes or a non-map."""
    if isinstance(frame, str):
        raise WireError(f"{what} is a text frame ({_short(frame)!r}), not binary msgpack")
    if not isinstance(frame, (bytes, bytearray, memoryview)):
        raise WireError(f"{what} is a {type(frame).__name__}, not a binary frame")
    try:
        out = msgpack.unpackb(bytes(frame), object_hook=_decode_hook, raw=False, strict_map_key=True, use_list=True)
    except WireError:
        raise
    except Exception as exc:  # msgpack's ExtraData, FormatError, StackError, UnicodeDecodeError, ValueError ...
        raise WireError(f"{what} is not msgpack ({type(exc).__name__}: {_short(str(exc))})") from None
    if not isinstance(out, dict):
        raise WireError(f"{what} is a msgpack {type(out).__name__}, not a map")
    bad = next((k for k in out if not isinstance(k, str)), None)
    if bad is not None:
        raise WireError(f"{what} has a non-string key {bad!r}")
    return out


def _short(text: str, n: int = 160) -> str:
    line = " ".join(str(text).split())
    return line if len(line) <= n else line[: n - 3] + "..."


def error_line(exc: BaseException | str) -> str:
    """The one-line text frame a server answers a failed request with."""
    text = exc if isinstance(exc, str) else f"{type(exc).__name__}: {exc}"
    return "error: " + _short(text, 400)
