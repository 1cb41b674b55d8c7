"""TFRecord files and tf.train.Example protobufs written for the importer tests: the inverse of what
`bench.logs.tfrecord` reads (bench itself only reads them)."""

from __future__ import annotations

import os
import struct

import numpy as np

from bench.logs.tfrecord import Value, masked_crc32c


def write_records(path: str | os.PathLike, records: list[bytes]) -> None:
    """Write records as a TFRecord file (the framing `iter_records` reads, both CRCs set)."""
    with open(path, "wb") as f:
        for rec in records:
            head = struct.pack("<Q", len(rec))
            f.write(head + struct.pack("<I", masked_crc32c(head)) + rec + struct.pack("<I", masked_crc32c(rec)))


def enc_varint(v: int) -> bytes:
    """A base-128 varint (a negative int64 as its 64-bit two's complement: ten bytes)."""
    v &= (1 << 64) - 1
    out = bytearray()
    while True:
        b = v & 0x7F
        v >>= 7
        if v:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def enc_field(number: int, payload: bytes) -> bytes:
    """A length-delimited field (wire type 2)."""
    return enc_varint((number << 3) | 2) + enc_varint(len(payload)) + payload


def encode_feature(value: Value) -> bytes:
    """Encode a tf.train.Feature from list[bytes|str], a float array or an int array."""
    if isinstance(value, list) and (not value or isinstance(value[0], (bytes, str))):
        items = [v.encode() if isinstance(v, str) else v for v in value]
        return enc_field(1, b"".join(enc_field(1, v) for v in items))
    arr = np.asarray(value)
    if arr.dtype.kind == "f":
        return enc_field(2, enc_field(1, arr.astype("<f4").tobytes()))
    return enc_field(3, enc_field(1, b"".join(enc_varint(int(v)) for v in arr.reshape(-1))))


def encode_example(features: dict[str, Value], feature_lists: dict[str, list[Value]] | None = None) -> bytes:
    """Encode an Example (or a SequenceExample when `feature_lists` is given)."""

    def entry(key: str, value: bytes) -> bytes:  # one map<string, M> entry
        return enc_field(1, enc_field(1, key.encode()) + enc_field(2, value))

    out = enc_field(1, b"".join(entry(k, encode_feature(v)) for k, v in features.items()))
    if feature_lists is not None:
        lists = {k: b"".join(enc_field(1, encode_feature(f)) for f in v) for k, v in feature_lists.items()}
        out += enc_field(2, b"".join(entry(k, v) for k, v in lists.items()))
    return out
