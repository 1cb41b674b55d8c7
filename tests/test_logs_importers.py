"""Importers: CSV, MATLAB .mat and RLDS (TFRecord + tf.train.Example parsed without TensorFlow)."""

from __future__ import annotations

import csv
import json
import shutil
import struct
from pathlib import Path

import numpy as np
import pytest

from bench.core.errors import DataError
from bench.logs import import_csv, import_mat, import_rlds, read_dataset, tfrecord, write_dataset
from tests.tfrecord_write import enc_field, enc_varint, encode_example, write_records

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
RLDS = SHARED / "formats" / "rlds_toy"
PENDULUM = SHARED / "real" / "simple_pendulum" / "data_measured.csv"
EMPS = SHARED / "real" / "emps" / "DATA_EMPS.mat"
SHARD = "toy_rlds/1.0.0/toy_rlds-train.tfrecord-00000-of-00001"


def _need(path: Path) -> Path:
    if not path.exists():
        pytest.skip(f"{path} not found (the shared data folder lives outside the repo)")
    return path


# ----------------------------------------------------------------------------- CSV


def test_pendulum_csv():
    path = _need(PENDULUM)
    ds = import_csv(path, time="time", state=["position", "velocity"], action=["torque"])
    with path.open() as f:
        rows = list(csv.DictReader(f))
    ep = ds.episodes[0]
    assert len(ds.episodes) == 1 and len(ep) == len(rows) == 1170
    assert ds.fps == 300.0  # 1 / median step 3.3338 ms = 299.96 Hz, snapped
    assert ds.features["observation.state"]["names"] == ["position", "velocity"]
    t = np.array([float(r["time"]) for r in rows])
    np.testing.assert_array_equal(ep.data["observation.state"][:, 1], np.float32([float(r["velocity"]) for r in rows]))
    np.testing.assert_array_equal(ep.data["action"][:, 0], np.float32([float(r["torque"]) for r in rows]))
    np.testing.assert_array_equal(ep.data["timestamp"], (t - t[0]).astype(np.float32))
    np.testing.assert_array_equal(ep.data["time_ns"][:, 0], np.round(t * 1e9).astype(np.int64))


def test_pendulum_round_trip(tmp_path):
    ds = import_csv(_need(PENDULUM), time="time", state=["position", "velocity"], action=["torque"])
    back = read_dataset(write_dataset(tmp_path / "p", ds))
    for k, v in ds.episodes[0].data.items():
        np.testing.assert_array_equal(back.episodes[0].data[k], v)


def test_csv_episodes_and_fps(tmp_path):
    path = tmp_path / "log.csv"
    path.write_text(
        "run,q1,q2,u\n" + "".join(f"{r},{i},{2 * i},{-i}\n" for r in ("a", "b") for i in range(3 + (r == "b")))
    )
    ds = import_csv(path, episode="run", action="u", fps=50)
    assert [len(e) for e in ds.episodes] == [3, 4]
    assert ds.features["observation.state"]["names"] == ["q1", "q2"]  # the numeric columns not used otherwise
    assert [e.meta["episode"] for e in ds.episodes] == ["a", "b"]
    np.testing.assert_array_equal(ds.episodes[1].data["timestamp"], np.float32([0, 0.02, 0.04, 0.06]))
    np.testing.assert_array_equal(ds.episodes[1].data["index"], [3, 4, 5, 6])


@pytest.mark.parametrize(
    "text, kwargs, pattern",
    [
        ("t,q\n0,1\n1,2\n", {"state": ["qq"], "time": "t"}, "column 'qq' not found; columns: t, q. Did you mean 'q'"),
        ("t,q\n0,a\n1,b\n", {"state": ["q"], "time": "t"}, "column 'q' is string, not numeric"),
        ("t,q\n0,1\n1,\n", {"state": ["q"], "time": "t"}, "column 'q' has an empty cell at row 1"),
        ("t,q\n0,1\n2,2\n1,3\n", {"state": ["q"], "time": "t"}, "column 't' is not increasing at row 2"),
        ("t,q\n0,1\n1,nan\n", {"state": ["q"], "time": "t"}, "column 'q' is NaN or inf at row 1"),
        ("t,q\n0,1\n1,2\n", {"state": ["q"]}, "field 'fps' is required"),
    ],
    ids=["unknown-column", "text", "empty-cell", "time-backwards", "nan", "no-fps"],
)
def test_csv_errors(tmp_path, text, kwargs, pattern):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(DataError, match=pattern) as err:
        import_csv(path, **kwargs)
    assert str(err.value).startswith(str(path)) and "\n" not in str(err.value)


# ----------------------------------------------------------------------------- MAT


def test_emps_mat():
    import scipy.io

    path = _need(EMPS)
    raw = scipy.io.loadmat(str(path))
    ds = import_mat(path, {"observation.state": ["qm"], "action": ["vir"]}, velocity=True)
    ep = ds.episodes[0]
    assert len(ds.episodes) == 1 and len(ep) == 24841 and ds.fps == 1000.0
    assert ds.features["observation.state"]["names"] == ["qm", "qm_dot"]
    assert ds.features["action"]["names"] == ["vir"]
    np.testing.assert_array_equal(ep.data["observation.state"][:, 0], raw["qm"][:, 0].astype(np.float32))
    np.testing.assert_array_equal(ep.data["action"][:, 0], raw["vir"][:, 0].astype(np.float32))
    t, qm = raw["t"][:, 0], raw["qm"][:, 0]
    np.testing.assert_allclose(
        ep.data["observation.state"][1:-1, 1], ((qm[2:] - qm[:-2]) / (t[2:] - t[:-2])).astype(np.float32), atol=1e-6
    )
    assert ep.meta["mat"] == pytest.approx({"gtau": 35.15065188, "kp": 160.18, "kv": 243.45})
    assert ep.data["timestamp"][-1] == np.float32(24.84)


def test_mat_generic(tmp_path):
    import scipy.io

    path = tmp_path / "log.mat"
    t = np.arange(6) * 0.01
    scipy.io.savemat(path, {"time": t[:, None], "q": np.arange(12.0).reshape(6, 2), "u": np.ones((1, 6)), "gain": 2.5})
    ds = import_mat(path, {"observation.state": "q", "action": ["u"]})
    ep = ds.episodes[0]
    assert ds.fps == 100.0 and ds.features["observation.state"]["names"] == ["q[0]", "q[1]"]
    np.testing.assert_array_equal(ep.data["observation.state"], np.arange(12.0, dtype=np.float32).reshape(6, 2))
    assert ep.data["action"].shape == (6, 1) and ep.meta["mat"] == {"gain": 2.5}
    default = import_mat(path)  # every length-T vector except time
    assert default.features["observation.state"]["names"] == ["q[0]", "q[1]", "u"]
    with pytest.raises(DataError, match="variable 'qq' not found; variables: time, q, u, gain. Did you mean 'q'"):
        import_mat(path, {"observation.state": ["qq"]})
    scipy.io.savemat(path, {"t": t[:, None], "q": np.zeros((5, 1))})
    with pytest.raises(DataError, match=r"variable 'q' has shape \(5, 1\); expected 6 samples like 't'"):
        import_mat(path, {"observation.state": ["q"]})


# ----------------------------------------------------------------------------- RLDS


def test_rlds_reproduces_reference_arrays():
    _need(RLDS)
    ref = np.load(RLDS / "reference_arrays.npz")
    ds = import_rlds(RLDS / "toy_rlds", fps=5)
    assert len(ds.episodes) == 3 and [len(e) for e in ds.episodes] == [5, 8, 3]
    for ep in ds.episodes:
        i = ep.meta["episode_id"]
        for field, key in (("state", "observation.state"), ("action", "action"), ("image", "observation.images.image")):
            want = ref[f"{i}/{field}"]
            assert ep.data[key].dtype == want.dtype and ep.data[key].shape == want.shape
            np.testing.assert_array_equal(ep.data[key], want)
        np.testing.assert_array_equal(ep.data["is_last"][:, 0], ref[f"{i}/is_last"])
    assert [e.meta["episode_id"] for e in ds.episodes] == [0, 1, 2]  # stored out of order, sorted by id
    assert ds.episodes[1].meta["file_path"] == "/raw/ep1.h5"
    assert list(ds.features)[:3] == ["observation.state", "action", "observation.images.image"]
    assert ds.tasks == [e.tasks[0] for e in ds.episodes]  # language_instruction -> task


def test_rlds_version_folder_and_shard_and_round_trip(tmp_path):
    _need(RLDS)
    a = import_rlds(RLDS / "toy_rlds" / "1.0.0", fps=5)
    b = import_rlds(RLDS / SHARD, fps=5)
    back = read_dataset(write_dataset(tmp_path / "r", a))
    for x, y, z in zip(a.episodes, b.episodes, back.episodes):
        for k in x.data:
            np.testing.assert_array_equal(x.data[k], y.data[k])
            np.testing.assert_array_equal(x.data[k], z.data[k])
        assert x.meta == z.meta


def test_rlds_needs_fps_and_known_fields():
    _need(RLDS)
    with pytest.raises(DataError, match="field 'fps' is required: RLDS stores no frame rate"):
        import_rlds(RLDS / "toy_rlds")
    with pytest.raises(DataError, match="names step feature 'observation/joints', which is not there"):
        import_rlds(RLDS / "toy_rlds", fps=5, state="observation/joints")


def _copy_rlds(tmp_path: Path) -> Path:
    dst = tmp_path / "toy_rlds"
    shutil.copytree(_need(RLDS) / "toy_rlds", dst)
    return dst


def test_rlds_crc_mismatch(tmp_path):
    root = _copy_rlds(tmp_path)
    shard = root / SHARD.split("/", 1)[1]
    blob = bytearray(shard.read_bytes())
    blob[0x70] ^= 0x01  # a byte of the first record's observation/state floats
    shard.write_bytes(bytes(blob))
    with pytest.raises(DataError, match=r"record 0 at byte 0: field 'data' fails its CRC"):
        import_rlds(root, fps=5)
    # Without the check the corruption passes silently: the reason the CRCs are verified.
    ref = np.load(RLDS / "reference_arrays.npz")
    ep = next(e for e in import_rlds(root, fps=5, verify=False).episodes if e.meta["episode_id"] == 0)
    assert not np.array_equal(ep.data["observation.state"], ref["0/state"])


def test_rlds_truncated(tmp_path):
    root = _copy_rlds(tmp_path)
    shard = root / SHARD.split("/", 1)[1]
    blob = shard.read_bytes()
    shard.write_bytes(blob[:-10])
    with pytest.raises(DataError, match=r"record 2 at byte \d+: truncated data"):
        import_rlds(root, fps=5)


# ----------------------------------------------------------------------------- TFRecord and protobuf


def test_crc32c_known_values():
    assert tfrecord.crc32c(b"123456789") == 0xE3069283  # the CRC-32C check value
    assert tfrecord.crc32c(bytes(32)) == 0x8A9136AA  # RFC 3720 B.4 test vector
    assert tfrecord.crc32c(b"") == 0
    rng = np.random.default_rng(0)
    for n in (32768, 40001, 300_000):  # the block-parallel path against the byte loop
        data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        assert tfrecord.crc32c(data) == tfrecord._raw_py(0xFFFFFFFF, data) ^ 0xFFFFFFFF


def test_records_round_trip(tmp_path):
    path = tmp_path / "x.tfrecord"
    records = [b"", b"abc", bytes(range(256)) * 200]
    write_records(path, records)
    assert [bytes(r) for r in tfrecord.iter_records(path)] == records


def test_example_wire_format():
    buf = encode_example({"f": np.float32([1.5, -2.0]), "i": np.array([3, -7, 2**40]), "b": [b"x", "y"]})
    features, lists = tfrecord.parse_example(buf)
    assert lists == {}
    np.testing.assert_array_equal(features["f"], np.float32([1.5, -2.0]))
    np.testing.assert_array_equal(features["i"], [3, -7, 2**40])  # negative int64 = 10-byte varint
    assert features["b"] == [b"x", b"y"]


def test_unpacked_repeated_fields():
    # Int64List / FloatList written element by element (not packed) must decode the same.
    def field(number: int, wire: int, payload: bytes) -> bytes:
        return enc_varint((number << 3) | wire) + payload

    ints = b"".join(field(1, 0, enc_varint(v)) for v in (5, 1 << 63 | 1))
    floats = b"".join(field(1, 5, struct.pack("<f", v)) for v in (0.25, 8.0))
    feat_i = enc_field(3, ints)
    feat_f = enc_field(2, floats)
    np.testing.assert_array_equal(tfrecord.parse_feature(memoryview(feat_i)), [5, -(2**63) + 1])
    np.testing.assert_array_equal(tfrecord.parse_feature(memoryview(feat_f)), np.float32([0.25, 8.0]))


def test_sequence_example_rlds(tmp_path):
    """A SequenceExample layout (context + one Feature per step) imports like the flat Example layout."""
    spec = {
        "featuresDict": {
            "features": {
                "episode_metadata": {
                    "featuresDict": {
                        "features": {"episode_id": {"tensor": {"dtype": "int32", "encoding": "none", "shape": {}}}}
                    }
                },
                "steps": {
                    "sequence": {
                        "feature": {
                            "featuresDict": {
                                "features": {
                                    "action": {
                                        "tensor": {
                                            "dtype": "float32",
                                            "encoding": "none",
                                            "shape": {"dimensions": ["2"]},
                                        }
                                    },
                                    "observation": {
                                        "featuresDict": {
                                            "features": {
                                                "state": {
                                                    "tensor": {
                                                        "dtype": "float32",
                                                        "encoding": "none",
                                                        "shape": {"dimensions": ["3"]},
                                                    }
                                                }
                                            }
                                        }
                                    },
                                    "is_last": {"tensor": {"dtype": "bool", "encoding": "none", "shape": {}}},
                                    "language_instruction": {"text": {}},
                                }
                            }
                        },
                        "length": "-1",
                    }
                },
            }
        }
    }
    folder = tmp_path / "seq" / "1.0.0"
    folder.mkdir(parents=True)
    (folder / "features.json").write_text(json.dumps(spec))
    rng = np.random.default_rng(0)
    truth = {}
    records = []
    for eid, t in ((7, 4), (3, 2)):
        state, action = rng.standard_normal((t, 3)).astype(np.float32), rng.standard_normal((t, 2)).astype(np.float32)
        truth[eid] = (state, action)
        records.append(
            encode_example(
                {"episode_metadata/episode_id": np.array([eid])},
                {
                    "steps/observation/state": list(state),
                    "steps/action": list(action),
                    "steps/is_last": [np.array([i == t - 1]) for i in range(t)],
                    "steps/language_instruction": [[f"task {eid}".encode()] for _ in range(t)],
                },
            )
        )
    write_records(folder / "seq-train.tfrecord-00000-of-00001", records)
    ds = import_rlds(tmp_path / "seq", fps=10)
    assert [e.meta["episode_id"] for e in ds.episodes] == [3, 7]
    for ep in ds.episodes:
        state, action = truth[ep.meta["episode_id"]]
        np.testing.assert_array_equal(ep.data["observation.state"], state)
        np.testing.assert_array_equal(ep.data["action"], action)
        assert ep.data["is_last"][:, 0].tolist() == [False] * (len(ep) - 1) + [True]
        assert ep.tasks == [f"task {ep.meta['episode_id']}"]
