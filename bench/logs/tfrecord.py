"""TFRecord files and tf.train.Example / SequenceExample protobufs, decoded without TensorFlow.

TFRecord framing, per record (all little-endian):

    uint64 length | uint32 masked_crc32c(length) | bytes data[length] | uint32 masked_crc32c(data)

with masked(c) = ((c >> 15) | (c << 17)) + 0xa282ead8 (mod 2**32). Both CRCs are verified.

The protobufs are read from the wire format directly (tensorflow/core/example/{example,feature}.proto):

    Example         { Features features = 1; }
    SequenceExample { Features context = 1; FeatureLists feature_lists = 2; }
    Features        { map<string, Feature> feature = 1; }
    FeatureLists    { map<string, FeatureList> feature_list = 1; }
    FeatureList     { repeated Feature feature = 1; }
    Feature         { oneof kind { BytesList bytes_list = 1; FloatList float_list = 2; Int64List int64_list = 3; } }
    BytesList { repeated bytes value = 1; }  FloatList { repeated float value = 1 [packed]; }
    Int64List { repeated int64 value = 1 [packed]; }
"""

from __future__ import annotations

import functools
import os
import struct
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar, Union

import numpy as np

from bench.core.errors import DataError

T = TypeVar("T")

# A decoded Feature: list[bytes] for bytes_list, float32 array for float_list, int64 array for int64_list.
Value = Union[list, np.ndarray]

# ----------------------------------------------------------------------------- CRC-32C (Castagnoli)

_POLY = 0x82F63B78  # reflected 0x1EDC6F41
_MASK_DELTA = 0xA282EAD8


def _make_table() -> list[int]:
    table = []
    for i in range(256):
        c = i
        for _ in range(8):
            c = (c >> 1) ^ (_POLY if c & 1 else 0)
        table.append(c)
    return table


_TABLE = _make_table()
_TABLE_NP = np.asarray(_TABLE, dtype=np.uint32)


def _raw_py(state: int, data: bytes | memoryview) -> int:
    """CRC register after feeding `data` (no pre/post inversion), one byte at a time."""
    t = _TABLE
    for b in bytes(data):
        state = t[(state ^ b) & 0xFF] ^ (state >> 8)
    return state


# The CRC register is linear over GF(2): feeding n zero bytes is a fixed 32x32 matrix. Matrices
# are lists of 32 column ints (column i = image of bit i), as in zlib's crc32_combine.
def _mat_vec(mat: list[int] | tuple[int, ...], vec: int) -> int:
    out, i = 0, 0
    while vec:
        if vec & 1:
            out ^= mat[i]
        vec >>= 1
        i += 1
    return out


def _mat_mul(a: list[int], b: list[int]) -> list[int]:
    return [_mat_vec(a, col) for col in b]


_ZERO_BYTE_POWERS: list[list[int]] = [[_raw_py(1 << i, b"\x00") for i in range(32)]]  # [k] = feed 2**k zero bytes


def _power(k: int) -> list[int]:
    while len(_ZERO_BYTE_POWERS) <= k:
        last = _ZERO_BYTE_POWERS[-1]
        _ZERO_BYTE_POWERS.append(_mat_mul(last, last))
    return _ZERO_BYTE_POWERS[k]


@functools.lru_cache(maxsize=64)
def _zeros_matrix(n: int) -> tuple[int, ...]:
    """Matrix of feeding `n` zero bytes to the register."""
    out = [1 << i for i in range(32)]
    for power in _bit_powers(n):
        out = _mat_mul(power, out)
    return tuple(out)


def _feed_zeros(n: int, vec: int) -> int:
    """Register `vec` after feeding `n` zero bytes."""
    for power in _bit_powers(n):
        vec = _mat_vec(power, vec)
    return vec


def _bit_powers(n: int) -> Iterator[list[int]]:
    """The matrices of feeding 2^k zero bytes, for each bit k set in `n` (lowest first)."""
    k = 0
    while n:
        if n & 1:
            yield _power(k)
        n >>= 1
        k += 1


def crc32c(data: bytes | memoryview) -> int:
    """CRC-32C of `data` (as used by TFRecord, iSCSI, ext4).

    Long inputs are split into equal blocks whose registers advance side by side in numpy, then
    combined with the zero-feeding matrix (crc(A|B) = Z^len(B) crc(A) xor crc(B) for the raw
    register), about 10x faster than a Python byte loop.
    """
    data = memoryview(data).cast("B")
    n = len(data)
    if n < 32768:
        return _raw_py(0xFFFFFFFF, data) ^ 0xFFFFFFFF
    lanes = int(min(4096, max(64, np.sqrt(n))))
    width = -(-n // lanes)
    buf = np.zeros(lanes * width, dtype=np.uint8)
    buf[lanes * width - n :] = np.frombuffer(data, dtype=np.uint8)  # leading zeros leave a raw CRC of 0 unchanged
    blocks = buf.reshape(lanes, width)
    regs = np.zeros(lanes, dtype=np.uint32)
    for j in range(width):
        regs = _TABLE_NP[(regs ^ blocks[:, j]) & 0xFF] ^ (regs >> np.uint32(8))
    step = _zeros_matrix(width)
    acc = 0
    for r in regs.tolist():
        acc = _mat_vec(step, acc) ^ r
    init = _feed_zeros(n, 0xFFFFFFFF)  # the 0xFFFFFFFF preset, carried through n bytes
    return (acc ^ init) ^ 0xFFFFFFFF


def masked_crc32c(data: bytes | memoryview) -> int:
    """TFRecord's masked CRC-32C."""
    c = crc32c(data)
    return (((c >> 15) | (c << 17)) + _MASK_DELTA) & 0xFFFFFFFF


# ----------------------------------------------------------------------------- TFRecord framing


def iter_records(path: str | os.PathLike, verify: bool = True) -> Iterator[memoryview]:
    """Yield the records of a TFRecord file; a truncated file or a CRC mismatch is a DataError.

    Args:
        path: an uncompressed TFRecord file.
        verify: check the length and data CRCs (on by default).
    """
    path = Path(path)
    try:
        blob = path.read_bytes()
    except OSError as exc:
        raise DataError(f"{path}: cannot read TFRecord file: {exc.strerror or exc}") from None
    view = memoryview(blob)
    pos, k, size = 0, 0, len(blob)
    while pos < size:
        if size - pos < 12:
            raise DataError(f"{path}: record {k} at byte {pos}: truncated header ({size - pos} of 12 bytes)")
        (length,) = struct.unpack_from("<Q", blob, pos)
        (length_crc,) = struct.unpack_from("<I", blob, pos + 8)
        if verify and masked_crc32c(view[pos : pos + 8]) != length_crc:
            raise DataError(f"{path}: record {k} at byte {pos}: field 'length' fails its CRC (corrupt file?)")
        start, end = pos + 12, pos + 12 + length
        if end + 4 > size:
            raise DataError(f"{path}: record {k} at byte {pos}: truncated data ({size - start} of {length + 4} bytes)")
        (data_crc,) = struct.unpack_from("<I", blob, end)
        record = view[start:end]
        if verify and masked_crc32c(record) != data_crc:
            raise DataError(f"{path}: record {k} at byte {pos}: field 'data' fails its CRC (corrupt file?)")
        yield record
        pos, k = end + 4, k + 1


# ----------------------------------------------------------------------------- protobuf wire format


class ProtoError(ValueError):
    """Malformed protobuf bytes."""


def _varint(buf: memoryview, pos: int) -> tuple[int, int]:
    result = shift = 0
    while True:
        if pos >= len(buf):
            raise ProtoError("truncated varint")
        b = buf[pos]
        pos += 1
        result |= (b & 0x7F) << shift
        if not b & 0x80:
            return result, pos
        shift += 7
        if shift > 63:
            raise ProtoError("varint longer than 10 bytes")


def _fields(buf: memoryview) -> Iterator[tuple[int, int, Any]]:
    """(field number, wire type, value): an int for varint fields, a memoryview for fixed and length-delimited."""
    pos, end = 0, len(buf)
    value: Any
    while pos < end:
        tag, pos = _varint(buf, pos)
        number, wire = tag >> 3, tag & 7
        if wire == 0:
            value, pos = _varint(buf, pos)
        elif wire == 1:
            if pos + 8 > end:
                raise ProtoError("truncated fixed64")
            value, pos = buf[pos : pos + 8], pos + 8
        elif wire == 2:
            length, pos = _varint(buf, pos)
            if pos + length > end:
                raise ProtoError(f"field {number}: length {length} runs past the message end")
            value, pos = buf[pos : pos + length], pos + length
        elif wire == 5:
            if pos + 4 > end:
                raise ProtoError("truncated fixed32")
            value, pos = buf[pos : pos + 4], pos + 4
        else:
            raise ProtoError(f"field {number}: unsupported wire type {wire}")
        yield number, wire, value


def _packed_varints(buf: memoryview) -> list[int]:
    out, pos = [], 0
    while pos < len(buf):
        v, pos = _varint(buf, pos)
        out.append(v)
    return out


def _to_int64(values: list[int]) -> np.ndarray:
    # int64 is encoded as its two's complement in 64 bits: fold values >= 2**63 back to negatives.
    return np.asarray(values, dtype=np.uint64).view(np.int64) if values else np.zeros(0, dtype=np.int64)


def parse_feature(buf: memoryview) -> Value:
    """Decode a tf.train.Feature: list[bytes], float32 array or int64 array (empty float array if unset)."""
    kind: Value = np.zeros(0, dtype=np.float32)
    for number, _, value in _fields(buf):
        if number == 1:  # BytesList
            kind = [bytes(v) for n, w, v in _fields(value) if n == 1 and w == 2]
        elif number == 2:  # FloatList
            parts = []
            for n, w, v in _fields(value):
                if n != 1:
                    continue
                if w == 2:
                    parts.append(np.frombuffer(v, dtype="<f4"))
                elif w == 5:
                    parts.append(np.frombuffer(v, dtype="<f4"))
                else:
                    raise ProtoError(f"FloatList.value with wire type {w}")
            kind = np.concatenate(parts).astype(np.float32) if parts else np.zeros(0, dtype=np.float32)
        elif number == 3:  # Int64List
            ints: list[int] = []
            for n, w, v in _fields(value):
                if n != 1:
                    continue
                if w == 2:
                    ints.extend(_packed_varints(v))
                elif w == 0:
                    ints.append(v)
                else:
                    raise ProtoError(f"Int64List.value with wire type {w}")
            kind = _to_int64(ints)
    return kind


def _parse_map(buf: memoryview, value_parser: Callable[[memoryview], T]) -> dict[str, T]:
    """A protobuf map<string, M> (field 1 of the enclosing message) as a dict."""
    out: dict[str, T] = {}
    for number, wire, entry in _fields(buf):
        if number != 1 or wire != 2:
            continue
        key, value = "", None
        for n, w, v in _fields(entry):
            if n == 1 and w == 2:
                key = bytes(v).decode("utf-8")
            elif n == 2 and w == 2:
                value = value_parser(v)
        out[key] = value if value is not None else value_parser(memoryview(b""))
    return out


def _parse_feature_list(buf: memoryview) -> list[Value]:
    return [parse_feature(v) for n, w, v in _fields(buf) if n == 1 and w == 2]


def parse_example(buf: bytes | memoryview) -> tuple[dict[str, Value], dict[str, list[Value]]]:
    """Decode a tf.train.Example or SequenceExample.

    Returns:
        (features, feature_lists): the Example's features (or the SequenceExample's context), and
        the SequenceExample's feature lists ({} for a plain Example).
    """
    buf = memoryview(buf).cast("B") if not isinstance(buf, memoryview) else buf
    features: dict[str, Value] = {}
    lists: dict[str, list[Value]] = {}
    for number, wire, value in _fields(buf):
        if number == 1 and wire == 2:
            features.update(_parse_map(value, parse_feature))
        elif number == 2 and wire == 2:
            lists.update(_parse_map(value, _parse_feature_list))
    return features, lists
