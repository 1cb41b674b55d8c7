"""Behaviour cloning (baselines.bc): data selection, normalisation, gripper as a sign, determinism,
and the checkpoint it writes loading as `policy=checkpoint`."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from baselines import bc
from baselines.checkpoint import load_policy, spec_path
from bench.core.errors import ConfigError, DataError
from bench.execution.recording import _expand
from bench.logs import from_arrays, write_dataset
from bench.protocols import STATE, ActionSpec, Feature
from bench.sims.robosuite import ACTION_NAMES
from suites.lift import OBS_FIELDS as OBS_NAMES

OBS_FLAT = _expand([f"{n}:{w}" for n, w in OBS_NAMES])


def _toy_dataset(root: Path, robots=("Panda", "Sawyer"), episodes=3, frames=40, seed=0, success=None) -> Path:
    """Episodes whose expert is known: a = clip(W obs), gripper = sign(obs[0]); names as the recorder writes them."""
    rng = np.random.default_rng(seed)
    w = np.random.default_rng(99).normal(scale=0.5, size=(6, 18))
    eps, tasks, meta = [], [], []
    for r in robots:
        for e in range(episodes):
            obs = rng.normal(size=(frames, 18)).astype(np.float32)
            act = np.zeros((frames, 7), np.float32)
            act[:, :3] = np.clip(obs @ w[:3].T, -1, 1)
            act[:, -1] = np.where(obs[:, 0] > 0, 1.0, -1.0)  # rotation dims stay 0, as in the Lift expert
            eps.append({"observation.state": obs, "action": act})
            tasks.append(f"Lift/{r}/default")
            ok = True if success is None else success(r, e)
            meta.append(
                {
                    "task": "Lift",
                    "robot": r,
                    "env": "default",
                    "split": "seen",
                    "condition": "nominal",
                    "seed": e,
                    "params": {},
                    "success_once": ok,
                    "success_at_end": ok,
                }
            )
    ds = from_arrays(eps, fps=20, task=tasks, meta=meta, names={"observation.state": OBS_FLAT, "action": ACTION_NAMES})
    return write_dataset(root, ds)


def _sha(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def test_obs_layout_inverts_the_recorder_names():
    assert bc.obs_layout(OBS_FLAT) == [[n, w] for n, w in OBS_NAMES]
    # a lone `x_0` is a width-1 field of that name (the recorder writes width-1 fields unsuffixed)
    assert bc.obs_layout(["a_0", "a_1", "b", "c_0"]) == [["a", 2], ["b", 1], ["c_0", 1]]


def test_selection_filters_robots_successes_and_counts(tmp_path: Path):
    data = _toy_dataset(tmp_path / "d", success=lambda r, e: not (r == "Sawyer" and e == 0))
    d = bc.load_demos([data], robots=["Sawyer"])
    assert [e["index"] for e in d.episodes] == [4, 5]  # Sawyer's failed episode 3 is dropped
    assert len(d.obs) == 2 * 40 and d.obs_names == [[n, w] for n, w in OBS_NAMES]
    d = bc.load_demos([data], max_episodes=1)
    assert [(e["robot"], e["index"]) for e in d.episodes] == [("Panda", 0), ("Sawyer", 4)]
    # max_episodes counts across datasets, in the order given
    other = _toy_dataset(tmp_path / "e", robots=("Panda",), seed=1)
    d = bc.load_demos([data, other], robots=["Panda"], max_episodes=4)
    assert [Path(e["source"]).name for e in d.episodes] == ["d", "d", "d", "e"]
    with pytest.raises(DataError, match="robots in the data: Panda, Sawyer"):
        bc.load_demos([data], robots=["UR5e"])


def test_learns_the_expert_and_saves_a_loadable_checkpoint(tmp_path: Path):
    data = _toy_dataset(tmp_path / "d", episodes=6)
    args = bc.Args(
        data=[str(data)],
        out=str(tmp_path / "ck" / "policy.safetensors"),
        epochs=60,
        hidden=[64, 64],
        batch_size=64,
        lr=3e-3,
    )
    path, info = bc.train(args)
    assert info["episodes"] == 12 and info["frames"] == 480 and info["gripper_accuracy"] > 0.97
    spec = json.loads(spec_path(path).read_text())
    assert spec["meta"]["run_name"] == "d__bc__s0" and spec["meta"]["gripper_dims"] == ["gripper"]
    assert spec["meta"]["constant_dims"] == ["droll", "dpitch", "dyaw"]  # never varied: reproduced exactly
    assert spec["normalization"]["action"]["std"][6] == 20.0  # gripper logit sharpness

    class Env:
        obs_spec = {STATE: Feature.state(OBS_NAMES)}
        action_spec = ActionSpec.box(ACTION_NAMES, -1.0, 1.0)

    policy = load_policy(path, Env())
    demos = bc.load_demos([data])  # the checkpoint, de-normalised and clipped, reproduces the expert's actions
    acts = np.array([policy.act({STATE: o}) for o in demos.obs])
    assert np.mean(np.abs(acts[:, :3] - demos.action[:, :3])) < 0.1
    assert np.abs(acts[:, 3:6]).max() < 1e-6
    assert np.mean(acts[:, -1] == demos.action[:, -1]) > 0.9  # the sign head gives exactly +-1


def test_same_seed_same_weights_other_seed_other_weights(tmp_path: Path):
    data = _toy_dataset(tmp_path / "d", episodes=2, frames=30)
    kw = dict(data=[str(data)], epochs=3, hidden=[32], batch_size=16, obs_noise=0.1)
    a, _ = bc.train(bc.Args(out=str(tmp_path / "a" / "p.safetensors"), **kw))
    b, _ = bc.train(bc.Args(out=str(tmp_path / "b" / "p.safetensors"), **kw))
    c, _ = bc.train(bc.Args(out=str(tmp_path / "c" / "p.safetensors"), seed=1, **kw))
    assert _sha(a) == _sha(b)  # bit-identical weights and spec
    assert _sha(a) != _sha(c)


def test_the_checkpoint_names_its_data_portably(tmp_path: Path):
    """A checkpoint names no folder of the machine that trained it: data outside the checkout by its folder's name
    (the same data in two scratch folders give the same sha256), data inside it relative to the checkout."""
    kw = dict(epochs=1, hidden=[8], batch_size=16)
    one = _toy_dataset(tmp_path / "one" / "d", episodes=1, frames=20)
    two = _toy_dataset(tmp_path / "two" / "d", episodes=1, frames=20)
    a, _ = bc.train(bc.Args(data=[str(one)], out=str(tmp_path / "a" / "p.safetensors"), **kw))
    b, _ = bc.train(bc.Args(data=[str(two)], out=str(tmp_path / "b" / "p.safetensors"), **kw))
    assert json.loads(spec_path(a).read_text())["meta"]["args"]["data"] == ["d"]
    assert str(tmp_path).encode() not in a.read_bytes()  # nor in the spec embedded in the safetensors header
    assert _sha(a) == _sha(b)
    repo = Path(bc.__file__).resolve().parents[1]
    assert bc.recorded_data([str(repo / "results" / "x"), "/elsewhere/demos/"]) == ["results/x", "demos"]


def test_gripper_sign_refuses_zero_commands(tmp_path: Path):
    data = _toy_dataset(tmp_path / "d", episodes=1, frames=10)
    d = bc.load_demos([data])
    d.action[0, -1] = 0.0
    with pytest.raises(DataError, match="gripper=regress"):
        bc.fit(d, bc.Args(epochs=1))
    model, spec, _ = bc.fit(d, bc.Args(epochs=1, gripper="regress"))  # plain MSE accepts it
    assert spec["meta"]["gripper_dims"] == []


@pytest.mark.parametrize(
    "argv, match",
    [
        (["data=[x]", "epoch=3"], "Did you mean 'epochs'"),
        (["data=[/nonexistent/ds]"], "not a dataset folder"),
        (["data=[x]", "gripper=soft"], "valid: sign, regress"),
        ([], "data: give at least one dataset folder"),
    ],
)
def test_bad_arguments_are_one_line_errors(argv, match):
    with pytest.raises(ConfigError, match=match):
        bc.main(argv)


def test_cli_help_lists_every_field_with_its_docstring():
    out = subprocess.run(
        [sys.executable, "-m", "baselines.bc", "--help"], capture_output=True, text=True, check=True
    ).stdout
    for name in ("data", "seed", "gripper_sharpness", "obs_noise"):
        assert f"  {name} " in out
    assert "seeds random, numpy and torch" in out


@pytest.mark.slow
def test_recorded_demos_train_a_policy_bench_run_loads(tmp_path: Path):
    """Real pipeline, tiny: 1 scripted Panda episode of 25 steps -> BC -> bench run policy=checkpoint."""
    run = [
        sys.executable,
        "-m",
        "bench",
        "run",
        "robots=[Panda]",
        "episodes=1",
        "horizon=25",
        "workers=1",
        f"out={tmp_path / 'runs'}",
    ]
    subprocess.run(
        run + ["policy=scripted", "run_id=demo", f"record={tmp_path / 'demo'}"], check=True, capture_output=True
    )
    path, info = bc.train(
        bc.Args(
            data=[str(tmp_path / "demo")],
            out=str(tmp_path / "ck" / "p.safetensors"),
            epochs=2,
            hidden=[32],
            successful_only=False,
        )
    )  # 25 steps: no lift yet
    assert info["frames"] == 25
    subprocess.run(run + ["policy=checkpoint", f"checkpoint={path}", "run_id=eval"], check=True, capture_output=True)
    rec = json.loads((tmp_path / "runs" / "eval" / "episodes.jsonl").read_text().splitlines()[0])
    assert rec["error"] is None and rec["length"] == 25 and rec["checkpoint_sha256"] == _sha(path)
