"""The robosuite fast path (bench.sims.robosuite_fast) against robosuite's own env.step.

Records, summary scores, and the simulator state after every step must be the same bytes with
`fast_path=true` (the default) and `fast_path=false`, for the same seeds, on every arm and scene of
the robosuite suites (the full sweep is `-m slow`; the default suite checks two arms and one scene).
"""

import json

import numpy as np
import pytest

from bench.api.sims import RobosuiteEnv
from bench.cli import main
from bench.records import read_records
from bench.sims import robosuite_fast
from suites.lift import LiftObserver

pytest.importorskip("robosuite")

ARMS = ["Panda", "Sawyer", "IIWA", "UR5e", "Kinova3", "Jaco", "XArm7"]


def _records_lines(path):
    """Each record without timing fields and run id, as the bytes it is written with (sorted by job)."""
    recs = sorted(read_records(path), key=lambda r: r.job_id)
    out = []
    for r in recs:
        d = json.loads(r.to_json())
        for k in ("wall_s", "finished_at", "worker_pid", "run_id"):
            d.pop(k)
        out.append(json.dumps(d, sort_keys=True))
    return out


def _scores(path):
    doc = json.loads(path.read_text())
    return json.dumps({k: doc[k] for k in ("cells", "aggregates", "gaps", "counts") if k in doc}, sort_keys=True)


def _both(tmp_path, *keys):
    for fast in ("true", "false"):
        argv = ["run", *keys, "workers=1", f"out={tmp_path}", f"run_id=fast-{fast}", f"fast_path={fast}"]
        assert main(argv) == 0, argv
    a, b = tmp_path / "fast-true", tmp_path / "fast-false"
    assert _records_lines(a / "episodes.jsonl") == _records_lines(b / "episodes.jsonl")
    assert _scores(a / "summary.json") == _scores(b / "summary.json")
    meta = [json.loads((d / "run.json").read_text()) for d in (a, b)]
    assert meta[0]["suite_spec"] == meta[1]["suite_spec"]  # the same suite either way: runs pair and merge
    return read_records(a / "episodes.jsonl")


def test_fast_path_applies_and_matches_env_step_state_by_state():
    """Every step: observation, reward, success, qpos, qvel, ctrl and the logged actuator inputs agree."""
    fast = RobosuiteEnv("Lift", "Panda", 40, LiftObserver())
    plain = RobosuiteEnv("Lift", "Panda", 40, LiftObserver(), fast=False)
    assert fast.fast_path_reason is None
    assert plain.fast_path_reason == "turned off (fast_path=false)"
    # the fast path's build compiles no robot-only model (robosuite's own build does; nothing reads it)
    assert fast.raw.robots[0].robot_model.mujoco_model is None
    assert plain.raw.robots[0].robot_model.mujoco_model is not None
    for seed in (0, 1):
        rng = np.random.default_rng(seed)
        a, b = fast.reset(seed), plain.reset(seed)
        assert a["state"].tobytes() == b["state"].tobytes()
        fast.inputs.start()
        plain.inputs.start()
        for t in range(40):
            action = rng.uniform(-1.2, 1.2, 7)  # beyond the action range too: clipping is part of the path
            (a, ra, *_), (b, rb, *_) = fast.step(action), plain.step(action)
            assert a["state"].tobytes() == b["state"].tobytes(), t
            assert ra == rb and fast.success() == plain.success()
            for field in ("qpos", "qvel", "ctrl", "act"):
                assert getattr(fast.mujoco.data, field).tobytes() == getattr(plain.mujoco.data, field).tobytes()
            assert fast.inputs.take().tobytes() == plain.inputs.take().tobytes()
        fast.inputs.stop()
        plain.inputs.stop()


def test_nothing_in_robosuite_reads_the_robot_only_model_the_fast_path_skips():
    """`bench.sims.robosuite._without_robot_only_models` leaves `robot_model.mujoco_model` None: robosuite must
    only ever set it (RobotModel) and ask for it to be set (Robot.load_model). A robosuite that reads it fails here."""
    import pathlib
    import re

    import robosuite

    uses = []
    for path in sorted(pathlib.Path(robosuite.__file__).parent.rglob("*.py")):
        for line in path.read_text(errors="replace").splitlines():
            if re.search(r"\bmujoco_model\b", line):
                uses.append(f"{path.name}:{line.strip()}")
    allowed = {
        "robot_model.py:self.mujoco_model: Optional[mujoco.MjModel] = None",
        "robot_model.py:def set_mujoco_model(self, mujoco_model: Optional[mujoco.MjModel] = None):",
        "robot_model.py:if mujoco_model is not None:",
        "robot_model.py:self.mujoco_model = mujoco_model",
        "robot_model.py:self.mujoco_model = self.get_model()",
        "robot.py:self.robot_model.set_mujoco_model()",
    }
    assert uses and set(uses) <= allowed, sorted(set(uses) - allowed)


def test_fast_path_refuses_what_it_was_not_checked_against():
    env = RobosuiteEnv("Lift", "Panda", 10, LiftObserver())
    env.raw.lite_physics = False
    assert robosuite_fast.reason_not(env.raw) == "lite_physics is off"
    env.raw.lite_physics = True
    osc = env.raw.robots[0].composite_controller.part_controllers["right"]
    osc.input_ref_frame = "world"
    assert "input_ref_frame" in robosuite_fast.reason_not(env.raw)


def test_records_equal_two_arms_scripted_with_a_perturbation(tmp_path):
    recs = _both(
        tmp_path,
        "suite=held_out_robots",
        "policy=scripted",
        "robots=[Panda,Jaco]",
        "episodes=1",
        "horizon=120",
        "perturb.mass=[3.0]",
        "perturb.action_noise=[0.05]",
    )
    assert {r.robot for r in recs} == {"Panda", "Jaco"} and all(r.error is None for r in recs)
    assert any(r.success_once for r in recs)  # real episodes: the expert lifts the cube


def test_records_equal_one_scene(tmp_path):
    _both(tmp_path, "suite=held_out_scenes", "policy=random", "envs=[table_up_12cm]", "episodes=2", "horizon=40")


@pytest.mark.slow
def test_records_equal_every_arm(tmp_path):
    recs = _both(
        tmp_path,
        "suite=held_out_robots",
        "policy=scripted",
        f"robots=[{','.join(ARMS)}]",
        "episodes=2",
        "horizon=200",
        "perturb.friction=[0.3]",
    )
    assert {r.robot for r in recs} == set(ARMS)


@pytest.mark.slow
def test_records_equal_every_scene(tmp_path):
    _both(tmp_path, "suite=held_out_scenes", "policy=scripted", "episodes=2", "horizon=150")


def test_overlapping_fast_builds_leave_plain_builds_compiling_their_robot_model():
    """Two fast-path builds overlapping in one process (threads of a worker) must not leave the skip on for a
    later plain build: the skip is a per-thread flag read by one permanent wrapper, not a swapped method."""
    import threading

    from robosuite.models.robots.robot_model import RobotModel

    from bench.sims.robosuite import _without_robot_only_models

    a_in, b_in, a_out = threading.Event(), threading.Event(), threading.Event()
    seen: dict[str, bool] = {}

    def first() -> None:
        with _without_robot_only_models(skip=True):
            a_in.set()
            b_in.wait(5)
        a_out.set()

    def second() -> None:
        a_in.wait(5)
        with _without_robot_only_models(skip=True):
            b_in.set()
            a_out.wait(5)  # the first build ends while this one is still inside

    threads = [threading.Thread(target=first), threading.Thread(target=second)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(10)

    class Probe:
        mujoco_model = None

        def get_model(self):
            seen["compiled"] = True
            return "model"

    probe = Probe()
    RobotModel.set_mujoco_model(probe)  # type: ignore[arg-type]  # only get_model and mujoco_model are touched
    assert seen.get("compiled") and probe.mujoco_model == "model"
