"""Cameras end to end on the real simulators: image observations in every MuJoCo suite, visual perturbations in
a run (recorded, paired, deterministic), episode videos and their place in the report, camera streams in
`record=` datasets, and the one-line errors for bad camera input. Rendering is EGL (software on CPU)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from bench import api
from bench.cli import main
from bench.core.errors import BenchError, ConfigError
from bench.core.video import decode_frames, probe
from bench.records import comparable

pytest.importorskip("robosuite")

LIFT = ["suite=held_out_robots", "robots=[Panda]", "workers=1", "image_size=32"]


def _plan(*argv: str):
    return api.plan(api.config_from_argv(list(argv)))


@pytest.mark.parametrize(
    "argv,keys",
    [
        (
            ["suite=held_out_robots", "robots=[Panda]", "obs=state+rgb"],
            {"state", "rgb.agentview", "rgb.robot0_eye_in_hand"},
        ),
        (["suite=held_out_scenes", "envs=[table_up_4cm]", "obs=rgb", "cameras=[frontview]"], {"rgb.frontview"}),
        (
            ["suite=held_out_envs", "tasks=[reach-v3]", "obs=state+rgb"],
            {"state", "task", "rgb.corner", "rgb.gripperPOV"},
        ),
        (["suite=gym", "env_id=HalfCheetah-v5", "obs=rgb"], {"rgb.track"}),
    ],
    ids=["held_out_robots", "held_out_scenes", "held_out_envs", "gym"],
)
def test_image_observations_declared_returned_and_deterministic(argv, keys):
    p = _plan(*argv, "image_size=24", "policy=random")
    cell = p.cells[0]
    spec = p.suite.obs_spec(cell)
    assert set(spec) == keys
    env = p.suite.make_env(cell, 3)
    try:
        assert set(env.obs_spec) == keys
        first = env.reset(7)
        for key in keys - {"state", "task"}:  # Meta-World's instruction is a string
            assert first[key].shape == (24, 24, 3) and first[key].dtype == np.uint8, key
            assert first[key].std() > 1, key  # a rendered scene
        stepped, *_ = env.step(np.zeros(env.action_spec.dim, np.float32))
        again = env.reset(7)  # same seed -> identical images
        for key in keys - {"state", "task"}:
            np.testing.assert_array_equal(again[key], first[key], err_msg=key)
        assert set(stepped) == keys
    finally:
        env.close()


def test_bad_camera_input_is_one_line_exit_2(capsys):
    cases = [
        (
            ["cameras=[agentveiw]"],
            "cameras: 'agentveiw' is not a camera of robosuite Lift; valid: frontview, birdview, "
            "agentview, sideview, robot0_robotview, robot0_eye_in_hand. Did you mean 'agentview'?",
        ),
        (["image_size=2000"], "image_size: 2000 is invalid; image sizes are whole numbers of pixels in [16, 1024]"),
        (["obs=pixels"], "obs: 'pixels' is not an observation mode; valid: state, rgb, state+rgb"),
        (["obs=rgb", "perturb.light=[0.5]"], "policy 'scripted' needs observation keys ['state']"),
        (["obs=state", "perturb.light=[0.5]"], "perturb.light changes only what the cameras see"),
    ]
    for extra, message in cases:
        assert main(["run", "suite=held_out_robots", "policy=scripted", "robots=[Panda]", "episodes=1", *extra]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and message in err, err
    # a policy that reads no image: the drop would be +0 [0, 0], which reads as robustness
    for policy in ("bc", "scripted"):
        argv = ["run", f"policy={policy}", "robots=[Panda]", "episodes=1", "obs=state+rgb", "perturb.light=[0.3]"]
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1, err
        assert f"perturb.light changes only camera images, and policy '{policy}' reads none (it reads state)" in err
    assert main(["run", "suite=gym", "env_id=InvertedPendulum-v5", "episodes=1", "perturb.light=[0.5]"]) == 2
    err = capsys.readouterr().err.strip()
    assert "perturb.light: InvertedPendulum-v5/default/default" in err and "has no camera rig" in err
    named = set(err.split("suites that render cameras: ")[1].split(", "))
    assert {"aloha", "gym", "held_out_envs", "held_out_robots", "held_out_scenes"} <= named, err
    assert main(["run", "suite=gym", "env_id=InvertedPendulum-v5", "episodes=1", "obs=rgb"]) == 2
    assert "has no cameras, so it cannot give image observations" in capsys.readouterr().err


def test_no_renderer_for_obs_rgb_is_one_line(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["MUJOCO_GL"] = "glfw"  # cannot start without a display
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "bench",
            "run",
            "suite=held_out_robots",
            "robots=[Panda]",
            "obs=rgb",
            "policy=random",
            "episodes=1",
            f"out={tmp_path}",
        ],
        capture_output=True,
        text=True,
        env=env,
        timeout=300,
    )
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "no offscreen OpenGL renderer could start with MUJOCO_GL=glfw" in lines[0]
    assert "set MUJOCO_GL=egl" in lines[0]
    assert not any(tmp_path.iterdir())  # nothing written


def test_visual_axes_in_a_run_recorded_paired_and_deterministic(tmp_path):
    argv = [
        *LIFT,
        "policy=random",
        "obs=rgb",
        "episodes=2",
        "horizon=3",
        f"out={tmp_path}",
        "perturb.light=[0.3]",
        "perturb.distractors=uniform(1,3)",
        "perturb.camera_pos.levels=[0.05]",
        "perturb.camera_pos.cameras=[agentview]",
    ]
    first = api.run(api.config_from_argv([*argv, "run_id=a"]))
    recs = {r.job_id: r for r in first.records}
    assert all(r.error is None for r in recs.values())
    assert recs["Lift/Panda/default|light=0.3|0"].params == {"light": 0.3}
    drawn = [recs[f"Lift/Panda/default|distractors~U(1,3)|{e}"].params["distractors"] for e in (0, 1)]
    assert all(1 <= d <= 3 for d in drawn)
    cam = recs["Lift/Panda/default|camera_pos=0.05|0"].params
    assert cam["camera_pos"] == 0.05 and len(cam["camera_pos.direction"]) == 3
    # paired by seed: the same initial state under every condition
    assert len({r.init_state_hash for r in recs.values() if r.episode == 0}) == 1
    second = api.run(api.config_from_argv([*argv, "run_id=b"]))
    assert sorted(map(comparable, first.records), key=str) == sorted(map(comparable, second.records), key=str)
    axes = {e["axis"] for e in first.summary["sensitivity"] if e.get("axis")}
    assert axes == {"light", "distractors", "camera_pos"}


def test_video_of_first_n_episodes_and_report(tmp_path):
    run = api.run(
        api.config_from_argv(
            [
                *LIFT,
                "policy=random",  # a policy that takes the images (a state-only one is refused a visual axis)
                "episodes=2",
                "horizon=6",
                "video=1",
                f"out={tmp_path}",
                "run_id=v",
                "obs=state+rgb",
                "perturb.table_color=[0.9]",
            ]
        )
    )
    videos = sorted((tmp_path / "v" / "videos").iterdir())
    assert [v.name for v in videos] == [
        "Lift__Panda__default--nominal--0.mp4",
        "Lift__Panda__default--table_color-0.9--0.mp4",
    ]  # episode 0 of each condition
    rec = next(r for r in run.records if r.job_id == "Lift/Panda/default|nominal|0")
    assert rec.extras["video"] == {"path": "videos/Lift__Panda__default--nominal--0.mp4", "frames": 7, "fps": 20}
    assert "video" not in next(r for r in run.records if r.episode == 1).extras
    info = probe(videos[0])
    assert (info["video.width"], info["video.height"], info["video.codec"]) == (
        64,
        32,
        "h264",
    )  # two cameras side by side
    frames = decode_frames(videos[0], np.arange(7) / 20)
    assert frames.shape == (7, 32, 64, 3)
    nominal, coloured = decode_frames(videos[0], [0.0]), decode_frames(videos[1], [0.0])
    assert np.abs(nominal.astype(int) - coloured).mean() > 2  # the visual perturbation is in the video
    out = tmp_path / "report"
    assert main(["report", str(tmp_path / "v"), f"out={out}"]) == 0
    page = (out / "index.html").read_text()
    assert "<video controls" in page and "videos/Lift__Panda__default--nominal--0.mp4" in page
    assert (out / "videos" / "Lift__Panda__default--nominal--0.mp4").is_file()
    assert "Robustness per axis" in page and "<td>table_color</td><td>visual</td>" in page


def test_record_writes_camera_streams_as_video_features(tmp_path):
    from bench.logs import info, read_dataset

    api.run(
        api.config_from_argv(
            [
                *LIFT,
                "policy=random",
                "episodes=2",
                "horizon=5",
                f"out={tmp_path}",
                "run_id=r",
                "obs=rgb",
                f"record={tmp_path / 'rec'}",
            ]
        )
    )
    ds = read_dataset(tmp_path / "rec")
    assert "observation.state" not in ds.features  # obs=rgb: the policy saw images only
    for cam in ("agentview", "robot0_eye_in_hand"):
        feat = ds.features[f"observation.images.{cam}"]
        assert feat["dtype"] == "video" and feat["shape"] == [32, 32, 3]
        assert ds.episodes[0].data[f"observation.images.{cam}"].shape == (5, 32, 32, 3)
    assert info(tmp_path / "rec")["features"]["observation.images.agentview"]["video"]["codec"] == "h264"
    assert json.loads((tmp_path / "rec" / "meta" / "info.json").read_text())["video_path"].startswith("videos/")


def test_video_needs_a_camera(tmp_path):
    with pytest.raises(ConfigError, match="video: InvertedPendulum-v5/default/default .* has no camera to film"):
        api.plan(api.config_from_argv(["suite=gym", "env_id=InvertedPendulum-v5", "video=1", f"out={tmp_path}"]))
    with pytest.raises(BenchError, match=r"video=-1: must be in \[0, "):
        api.plan(api.config_from_argv([*LIFT, "video=-1"]))


def test_robustness_table_pools_levels_and_pairs_by_seed():
    from bench.scoring.robustness import table
    from tests.fixtures import record

    def rec(cond, axis, ep, ok):
        return record(
            ok, run_id="x", task="T", robot="R", env="E", condition=cond, axis=axis, episode=ep, seed=ep, length=1
        )

    recs = [rec("nominal", None, e, True) for e in range(4)]
    recs += [rec("light=0.2", "light", e, e < 1) for e in range(4)] + [
        rec("light=0.5", "light", e, e < 3) for e in range(4)
    ]
    recs += [rec("texture=1", "texture", e, True) for e in range(4)]
    rows = table(recs, "success_once", np.random.default_rng(0), n_boot=200)
    assert [r["axis"] for r in rows] == ["light", "texture"]  # most harmful first
    light = rows[0]
    assert light["pairs"] == 8 and light["nominal"] == 1.0 and light["perturbed"] == 0.5
    assert light["drop"]["value"] == pytest.approx(0.5) and light["relative_drop"] == pytest.approx(0.5)
    assert light["kind"] == "visual" and light["levels"] == ["light=0.2", "light=0.5"]
    assert rows[1]["drop"]["value"] == 0.0
