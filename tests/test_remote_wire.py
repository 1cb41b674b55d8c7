"""The remote-policy wire format against openpi-client's own serializer, obs_map parsing, latency pooling."""

from __future__ import annotations

import pickle
import sys

import msgpack
import numpy as np
import pytest

from bench.core.errors import ConfigError
from bench.protocols import STATE, Feature
from bench.remote import latency, obs_map, wire

openpi_msgpack = pytest.importorskip("openpi_client.msgpack_numpy", reason="openpi-client is in the test extra")

DTYPES = ["bool", "uint8", "int16", "int32", "int64", "uint64", "float16", "float32", "float64", ">f4", "<U5"]


@pytest.mark.parametrize("dtype", DTYPES)
def test_arrays_round_trip_both_ways_with_openpi(dtype):
    rng = np.random.default_rng(0)
    arr = (rng.normal(size=(3, 4)) * 50).astype(dtype) if dtype != "<U5" else np.array([["ab", "cdefg"]], dtype)
    msg = {"a": arr, "s": "pick up the cube", "n": np.float32(1.5), "nested": {"x": arr[:1]}}
    for packed, unpack in ((wire.encode(msg), openpi_msgpack.unpackb), (openpi_msgpack.packb(msg), wire.decode)):
        out = unpack(packed)
        assert out["a"].dtype == arr.dtype and out["a"].shape == arr.shape and np.array_equal(out["a"], arr)
        assert out["s"] == "pick up the cube" and out["n"] == np.float32(1.5) and type(out["n"]) is np.float32
        assert np.array_equal(out["nested"]["x"], arr[:1])
    assert wire.encode(msg) == openpi_msgpack.packb(msg)  # byte for byte what openpi's client sends
    assert wire.decode(wire.encode(msg))["a"].flags.writeable  # like an in-process observation


def test_non_contiguous_and_empty_arrays():
    arr = np.arange(24, dtype=np.float32).reshape(4, 6)[:, ::2]
    assert np.array_equal(wire.decode(wire.encode({"a": arr}))["a"], arr)
    empty = np.zeros((0, 7), np.float32)
    assert wire.decode(wire.encode({"a": empty}))["a"].shape == (0, 7)


def _ndarray(dtype: str, shape: list, data: bytes) -> bytes:
    return msgpack.packb(
        {"obs": {b"__ndarray__": True, b"data": data, b"dtype": dtype, b"shape": shape}}, use_bin_type=True
    )


@pytest.mark.parametrize(
    "frame, match",
    [
        (_ndarray("|O", [1], b"\0" * 8), r"dtype object is not allowed"),
        (_ndarray("|V8", [1], b"\0" * 8), r"dtype \|V8 is not allowed"),
        (_ndarray("<c8", [1], b"\0" * 8), r"dtype complex64 is not allowed"),
        (_ndarray("[('a', '<f4')]", [1], b"\0" * 4), r"not a numpy dtype string|not allowed"),
        (_ndarray("<f4", [3], b"\0" * 8), r"needs 12 bytes, got 8"),
        (_ndarray("<f4", [-1], b""), r"shape must be a list of at most 8 non-negative integers"),
        (_ndarray("<f4", [1] * 9, b"\0" * 4), r"at most 8"),
        (_ndarray("nonsense", [1], b"\0" * 4), r"not a numpy dtype string"),
        (b"\x93\x01\x02", r"is not msgpack|is a msgpack list"),
        (msgpack.packb([1, 2, 3]), r"is a msgpack list, not a map"),
        (msgpack.packb({1: 2}), r"non-string key|not msgpack"),
        (b"\xc1garbage", r"is not msgpack"),
        (pickle.dumps({"state": np.zeros(3)}), r"is not msgpack|not a map"),
        ("error: a text frame", r"is a text frame"),
    ],
)
def test_bad_frames_are_refused_with_the_reason(frame, match):
    with pytest.raises(wire.WireError, match=match):
        wire.decode(frame)


def test_no_pickle_on_the_wire():
    with pytest.raises(wire.WireError, match="cannot send an array of dtype object"):
        wire.encode({"a": np.array([object()], dtype=object)})
    with pytest.raises(wire.WireError, match="cannot send a"):
        wire.encode({"a": object()})
    import bench.remote.client
    import bench.remote.server  # noqa: F401

    for name in ("wire", "client", "server", "serving", "obs_map", "latency"):
        src = open(sys.modules[f"bench.remote.{name}"].__file__).read()
        assert "import pickle" not in src and "pickle.load" not in src and "allow_pickle=True" not in src


SPEC = {STATE: Feature.state([("eef_pos", 3), ("gripper", 1), ("object_pos", 3)]), "rgb.front": Feature.rgb(4, 4)}


def test_obs_map_selects_renames_and_slices_fields():
    entries = obs_map.parse(
        [
            "observation/image:rgb.front",
            "observation/state:state.eef_pos+state.gripper",
            "observation.environment_state:state.object_pos",
            "prompt:task",
            "raw:state",
        ]
    )
    obs_map.check(entries, SPEC, "toy")
    assert obs_map.env_keys(entries) == ("rgb.front", STATE)
    img = np.zeros((4, 4, 3), np.uint8)
    state = np.arange(7, dtype=np.float32)
    msg = obs_map.ClientMap(entries, SPEC, "Lift")({STATE: state, "rgb.front": img})
    assert list(msg) == ["observation/image", "observation/state", "observation.environment_state", "prompt", "raw"]
    assert msg["observation/state"].tolist() == [0, 1, 2, 3] and msg["observation/state"].dtype == np.float32
    assert msg["observation.environment_state"].tolist() == [4, 5, 6] and msg["prompt"] == "Lift"
    assert msg["observation/image"] is img and msg["raw"] is state
    # the env's own instruction wins over the cell's task name
    assert (
        obs_map.ClientMap(entries, SPEC, "Lift")({STATE: state, "rgb.front": img, "task": "lift it"})["prompt"]
        == "lift it"
    )
    # no map: everything under bench's names, plus the task
    assert sorted(obs_map.ClientMap(None, SPEC, "Lift")({STATE: state})) == ["state", "task"]
    assert obs_map.server_map(obs_map.parse(["observation/state:state", "prompt:task"])) == {
        "observation/state": "state",
        "prompt": "task",
    }


@pytest.mark.parametrize(
    "entries, match",
    [
        (["observation/state"], r"entry 'observation/state' is not WIRE_KEY:SOURCE"),
        (["a:velocity"], r"source 'velocity' is not state, state.<field>, rgb.<camera>, depth.<camera> or task"),
        (["a:state", "a:task"], r"wire key 'a' is given twice"),
        (["__bench__:state"], r"reserved"),
        (["a:state.eef_pos+gripper"], r"a field selection is state.<field>"),
    ],
)
def test_obs_map_syntax_errors(entries, match):
    with pytest.raises(ConfigError, match=match):
        obs_map.parse(entries)


def test_obs_map_sources_are_checked_against_the_spec():
    with pytest.raises(
        ConfigError,
        match=r"reads 'rgb.wrist', which toy does not provide; it provides state, "
        r"rgb.front. Did you mean 'rgb.front'\?",
    ):
        obs_map.check(obs_map.parse(["img:rgb.wrist"]), SPEC, "toy")
    with pytest.raises(
        ConfigError,
        match=r"the state of toy has no field 'eef_quat'; fields: eef_pos, gripper, "
        r"object_pos",
    ):
        obs_map.check(obs_map.parse(["s:state.eef_quat"]), SPEC, "toy")
    with pytest.raises(ConfigError, match="a server can only rename whole entries"):
        obs_map.server_map(obs_map.parse(["s:state.eef_pos"]))


def test_latency_histograms_pool_exactly():
    rng = np.random.default_rng(1)
    a, b = rng.lognormal(np.log(2e-4), 0.3, 300), rng.lognormal(np.log(5e-3), 0.2, 100)
    sa, sb = latency.episode_stats(a, [0.01] * 300, 20.0), latency.episode_stats(b, [], 20.0)
    assert sa["requests"] == 300 and abs(sa["rtt_ms"]["p50"] - np.median(a) * 1000) < 1e-3
    assert sa["rtt_steps_p50"] == pytest.approx(np.median(a) * 20, abs=1e-4) and "server_ms" not in sb
    pooled = latency.pool([sa, sb, {"requests": 0}])
    both = np.concatenate([a, b]) * 1000
    assert pooled["requests"] == 400 and pooled["episodes"] == 2
    for q, key in ((0.5, "p50"), (0.9, "p90"), (0.99, "p99")):  # within one bin (12%)
        assert abs(np.log10(pooled["rtt_ms"][key] / np.quantile(both, q))) <= 1 / latency.PER_DECADE
    assert pooled["rtt_ms"]["max"] == pytest.approx(both.max(), abs=1e-3)
    assert pooled["rtt_steps"]["p50"] == pytest.approx(pooled["rtt_ms"]["p50"] * 20 / 1000, abs=1e-4)
    assert latency.pool([]) is None and latency.episode_stats([], [], 20.0) == {"requests": 0}
