"""Config: Hydra-style overrides onto typed frozen configs; errors are one line with a suggestion."""

import dataclasses

import pytest

from bench.api import RunConfig
from bench.config import build, parse_kv, split_args
from bench.errors import ConfigError


def test_overrides_nested_and_lists():
    cfg = build(RunConfig, ["episodes=3", "robots=[UR5e,IIWA]", "perturb.friction=[0.5,1.0]", "seed=7"])
    assert cfg.episodes == 3 and cfg.seed == 7
    assert cfg.robots == ["UR5e", "IIWA"]
    assert cfg.perturb == {"friction": [0.5, 1.0]}


def test_config_is_frozen():
    cfg = build(RunConfig, [])
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.episodes = 5  # type: ignore[misc]


def test_unknown_key_suggests_closest():
    with pytest.raises(ConfigError, match=r"unknown key 'episods'.*Did you mean 'episodes'\?"):
        build(RunConfig, ["episods=3"])


def test_wrong_type_names_key():
    with pytest.raises(ConfigError, match=r"bad value for 'episodes'"):
        build(RunConfig, ["episodes=many"])


def test_not_key_value():
    with pytest.raises(ConfigError, match="is not key=value"):
        build(RunConfig, ["=3"])


def test_split_and_parse_kv():
    pos, kv = parse_kv(["info", "DIR", "out=x", "a.b=[1,2]"])
    assert pos == ["info", "DIR"] and kv == {"out": "x", "a": {"b": [1, 2]}}
    assert split_args(["a=1", "b"]) == (["b"], ["a=1"])
