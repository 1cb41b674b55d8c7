"""Image BC (baselines/bc_image.py): trains from a LeRobot dataset with video camera features, bit-reproducibly,
and its checkpoint runs as policy=bc_image with checks against the suite's cameras before anything runs."""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
from video_frames import frames

from baselines import bc_image
from bench import api
from bench.core.errors import ConfigError
from bench.logs import from_arrays, write_dataset
from bench.protocols import PolicyContext

pytest.importorskip("torch")

STATE_NAMES = (
    [f"eef_pos_{i}" for i in range(3)]
    + [f"eef_quat_rel_{i}" for i in range(4)]
    + ["gripper_opening"]
    + [f"object_pos_{i}" for i in range(3)]
    + [f"object_quat_{i}" for i in range(4)]
    + [f"gripper_to_object_{i}" for i in range(3)]
)
ACTIONS = ["dx", "dy", "dz", "droll", "dpitch", "dyaw", "gripper"]


def _demos(tmp_path: Path, size: int = 32) -> Path:
    rng = np.random.default_rng(0)
    eps, start = [], 0
    for _e in range(3):
        t = 12
        act = rng.uniform(-1, 1, (t, 7)).astype(np.float32)
        act[:, -1] = np.where(np.arange(t) > 5, 1.0, -1.0)
        eps.append(
            {
                "observation.state": rng.standard_normal((t, 18)),
                "action": act,
                "observation.images.agentview": frames(t, size, size, 0, start),
                "observation.images.robot0_eye_in_hand": frames(t, size, size, 1, start),
            }
        )
        start += t
    ds = from_arrays(
        eps,
        fps=20,
        names={"observation.state": STATE_NAMES, "action": ACTIONS},
        video=True,
        meta=[{"robot": "Panda", "success_once": True}] * 3,
    )
    return write_dataset(tmp_path / "demos", ds)


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def test_trains_reproducibly_and_acts(tmp_path):
    data = _demos(tmp_path)
    args = dict(data=[str(data)], epochs=2, batch_size=8, channels=[8, 8], hidden=32, threads=1)
    a = bc_image.train(bc_image.Args(out=str(tmp_path / "a" / "p.safetensors"), **args))
    b = bc_image.train(bc_image.Args(out=str(tmp_path / "b" / "p.safetensors"), **args))
    assert a["frames"] == 36 and a["episodes"] == 3 and np.isfinite(a["losses"]).all()
    assert _sha(Path(a["checkpoint"])) == _sha(Path(b["checkpoint"]))  # same data, seed -> same weights
    plugin = bc_image.ImageBCPlugin()
    opts = bc_image.Options(checkpoint=a["checkpoint"])
    assert plugin.obs_keys(opts) == ("state", "rgb.agentview", "rgb.robot0_eye_in_hand")
    p = api.plan(
        api.config_from_argv(
            [
                "suite=held_out_robots",
                "robots=[Panda]",
                "obs=state+rgb",
                "image_size=32",
                "policy=bc_image",
                f"checkpoint={a['checkpoint']}",
            ]
        )
    )
    spec = p.suite.obs_spec(p.cells[0])

    class Env:  # what make() reads from an env: its declared spec and action bounds
        obs_spec = spec
        action_spec = type("A", (), {"low": -np.ones(7), "high": np.ones(7)})()

    policy = plugin.make(p.cells[0], Env(), PolicyContext(opts, p.suite, 0, 10))
    obs = {
        "state": np.zeros(18, np.float32),
        "rgb.agentview": frames(1, 32, 32)[0],
        "rgb.robot0_eye_in_hand": frames(1, 32, 32, 1)[0],
    }
    act = policy.act(obs)
    assert act.shape == (7,) and act.dtype == np.float32 and np.all(np.abs(act) <= 1)
    with pytest.raises(
        ConfigError, match=r"trained on rgb.agentview \[32, 32, 3\]; suite held_out_robots gives \[64, 64, 3\]"
    ):
        api.plan(
            api.config_from_argv(
                [
                    "suite=held_out_robots",
                    "robots=[Panda]",
                    "obs=state+rgb",
                    "image_size=64",
                    "policy=bc_image",
                    f"checkpoint={a['checkpoint']}",
                ]
            )
        )
    with pytest.raises(ConfigError, match="needs observation keys"):
        api.plan(
            api.config_from_argv(
                ["suite=held_out_robots", "robots=[Panda]", "policy=bc_image", f"checkpoint={a['checkpoint']}"]
            )
        )


def test_bad_training_input(tmp_path):
    data = _demos(tmp_path)
    with pytest.raises(ConfigError, match="proprio: 'joint_pos' is not a field"):
        bc_image.load(bc_image.Args(data=[str(data)], proprio=["joint_pos"]))
    with pytest.raises(ConfigError, match="cameras: 'frontview' is not a camera"):
        bc_image.load(bc_image.Args(data=[str(data)], cameras=["frontview"]))
    with pytest.raises(ConfigError, match="checkpoint: policy=bc_image needs checkpoint="):
        bc_image.ImageBCPlugin().obs_keys(bc_image.Options())
