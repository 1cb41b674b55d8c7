"""`bench replay`: open-loop replay measures the sim-real gap, batched replay equals a step loop, bad input exits 2.

Logs come from `bench.calibrate.generate` (a 3-joint arm under PD tracking, sensor noise 5e-4 rad and
1e-2 rad/s), from the plain arm and from arms with one physical change; all are replayed in the
plain arm (`models/arm3.xml`).
"""

import json
import re

import mujoco
import numpy as np
import pytest
import yaml

from bench.calibrate.generate import ARM, simulate_arm, spec_dict, write_case
from bench.cli import main
from bench.logs import from_arrays, write_dataset
from bench.replay import ReplayConfig, replay_logs
from tests.fixtures import recorded

HORIZONS = ("one_step", "k_step", "free_run")


def _strict_json(path):
    def bad(const):
        raise AssertionError(f"{path}: {const} in JSON")

    return json.loads(path.read_text(), parse_constant=bad)


@pytest.fixture(scope="module")
def nominal_spec(tmp_path_factory):
    """A spec for the plain arm as it is (the model the logs are replayed in)."""
    raw = spec_dict(None, model_file=str(ARM))
    raw["params"] = []
    path = tmp_path_factory.mktemp("spec") / "spec.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


@pytest.fixture(scope="module")
def cases(tmp_path_factory):
    """Logs of the plain arm and of two changed arms: 2 episodes x 2 s at 100 Hz each."""
    root = tmp_path_factory.mktemp("cases")
    return {
        str(e): write_case(root / str(e), e, episodes=2, duration=2.0, seed=0) / "logs"
        for e in (None, "payload_mass", "viscous_damping")
    }


@pytest.fixture(scope="module")
def nominal_replay(cases, nominal_spec, tmp_path_factory):
    out = tmp_path_factory.mktemp("replay")
    assert main(["replay", f"logs={cases['None']}", f"spec={nominal_spec}", "k=10", f"out={out}"]) == 0
    return out


@pytest.mark.parametrize("effect", ["payload_mass", "viscous_damping"])
def test_logs_of_a_changed_arm_replay_with_a_larger_error(cases, nominal_spec, nominal_replay, tmp_path, effect):
    """Measured: nominal logs 0.0023 / 0.0027 / 0.0017 (one-step / k-step / free-run NRMSE, the sensor noise);
    payload 0.0027 / 0.044 / 1.23; damping 0.0038 / 0.093 / 0.76."""
    assert main(["replay", f"logs={cases[effect]}", f"spec={nominal_spec}", "k=10", f"out={tmp_path}"]) == 0
    nom = _strict_json(nominal_replay / "replay.json")["horizons"]
    gap = _strict_json(tmp_path / "replay.json")["horizons"]
    assert nom["free_run"]["nrmse"] < 0.01 and nom["k_step"]["nrmse"] < 0.01  # the plain arm replays to noise
    assert gap["one_step"]["nrmse"] > nom["one_step"]["nrmse"]  # 10 ms ahead: mostly sensor noise
    assert gap["k_step"]["nrmse"] > 5 * nom["k_step"]["nrmse"]
    assert gap["free_run"]["nrmse"] > 20 * nom["free_run"]["nrmse"]
    assert gap["free_run"]["nrmse"] > gap["k_step"]["nrmse"] > gap["one_step"]["nrmse"]  # errors grow with horizon


def test_replay_json_and_plot(nominal_replay, cases):
    doc = _strict_json(nominal_replay / "replay.json")
    assert doc["schema"] == "bench.replay/1" and doc["backend"] == "mujoco.rollout"
    assert doc["joints"] == ["j1", "j2", "j3"] and doc["episodes"] == [0, 1] and doc["frames"] == 400
    assert doc["substeps"] == 5 and doc["k"] == 10
    for h, k in zip(HORIZONS, (1, 10, None)):
        entry = doc["horizons"][h]
        assert entry["k"] == k and set(entry["per_joint"]) == {"j1", "j2", "j3"}
        assert entry["nrmse"] == pytest.approx(np.mean([v["nrmse"] for v in entry["per_joint"].values()]))
    assert doc["horizons"]["one_step"]["segments"] == 2 * 199  # every frame but the last, per episode
    assert doc["horizons"]["free_run"]["segments"] == 2
    assert [r["episode"] for r in doc["per_episode"]] == [0, 1]
    png = nominal_replay / doc["plot"]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


def _step_loop(model, qpos, qvel, ctrl, start, length, substeps):
    """What `mujoco.rollout` replaces: mj_step per substep from a logged state under the logged command."""
    d = mujoco.MjData(model)
    d.qpos[:], d.qvel[:] = qpos[start], qvel[start]
    out = np.empty((length, model.nq))
    for f in range(length):
        d.ctrl[:] = ctrl[start + f]
        for _ in range(substeps):
            mujoco.mj_step(model, d)
        out[f] = d.qpos
    return out


def _arm_simulator(spec_path, episodes: int, duration: float):
    """The nominal arm's model, a recording of Coulomb-friction episodes, substeps, and a `Simulator` of them."""
    from bench.replay.data import extract
    from bench.replay.simulate import Simulator, prepare_model
    from bench.replay.spec import load_model, load_signal_map

    spec, _ = load_signal_map(spec_path)
    eps, _ = simulate_arm("coulomb_friction", episodes=episodes, duration=duration, seed=1)
    rec = extract(spec, eps, 100.0, nq=3, nv=3, nu=3)
    model, substeps = prepare_model(load_model(spec.model), rec.fps, spec.substeps)
    return model, rec, substeps, Simulator(model, rec, substeps)


def test_batched_replay_equals_a_python_step_loop(nominal_spec):
    from bench.replay.data import Window
    from bench.replay.metrics import horizon_errors
    from bench.replay.simulate import as_given

    model, rec, substeps, sim = _arm_simulator(nominal_spec, episodes=2, duration=0.5)
    errors = horizon_errors(sim, as_given(model, rec, substeps), rec, [Window(0, 0, 50), Window(1, 0, 50)], 7)
    sim.close()
    for h, e in errors.items():
        for s, start in enumerate(e.start):
            n = int(e.mask[s].sum())
            ref = _step_loop(model, rec.qpos, rec.qvel, rec.ctrl, int(start), n, substeps)
            np.testing.assert_allclose(e.pred[s, :n], ref, rtol=0, atol=1e-12, err_msg=f"{h} segment {s}")


def test_no_segment_simulates_to_an_empty_batch(nominal_spec):
    """An empty set of segments (a split that held nothing out) is an empty result, not a crash in MuJoCo's rollout."""
    from bench.replay.simulate import Segments, as_given

    model, rec, substeps, sim = _arm_simulator(nominal_spec, episodes=1, duration=0.2)
    try:
        out = sim.run([as_given(model, rec, substeps)], Segments(np.zeros(0, np.int64), 5))
    finally:
        sim.close()
    assert out.shape == (1, 0, 5, 6)


def test_k_of_one_is_the_one_step_error(cases, nominal_spec):
    doc = replay_logs(ReplayConfig(logs=str(cases["None"]), spec=str(nominal_spec), k=1, episodes=[1])).doc
    assert doc["episodes"] == [1]
    assert doc["horizons"]["k_step"]["per_joint"] == doc["horizons"]["one_step"]["per_joint"]


def test_episodes_shorter_than_k_replay_to_their_end_and_plot(cases, nominal_spec, tmp_path):
    """k longer than every episode (200 frames): one k-step horizon per episode, to its end: the free run.

    Each horizon stops at its episode's last frame (it used to run on into the next episode's frames,
    and the plot failed on the length mismatch)."""
    out = tmp_path / "out"
    assert main(["replay", f"logs={cases['None']}", f"spec={nominal_spec}", "k=1000", f"out={out}"]) == 0
    doc = _strict_json(out / "replay.json")
    assert doc["horizons"]["k_step"]["per_joint"] == doc["horizons"]["free_run"]["per_joint"]
    assert doc["horizons"]["k_step"]["frames"] == doc["horizons"]["free_run"]["frames"] == doc["frames"] - 2
    assert any("2 of 2 episode(s) are shorter than k = 1000 frames" in n for n in doc["notes"])
    assert (out / "replay.png").stat().st_size > 0
    # one episode shorter than k, one longer: the short one's horizon ends with it, the long one is covered
    a, _ = simulate_arm(None, episodes=1, duration=0.1, seed=1)  # 10 frames
    b, _ = simulate_arm(None, episodes=1, duration=0.5, seed=2)  # 50 frames
    write_dataset(tmp_path / "mixed", from_arrays([a[0], b[0]], fps=100))
    rep = replay_logs(ReplayConfig(logs=str(tmp_path / "mixed"), spec=str(nominal_spec), k=20))
    k = rep.errors["k_step"]
    assert k.mask[0].sum() == 9 and k.mask[1:].all()  # the 10-frame episode: 9 frames ahead of its start
    assert rep.doc["horizons"]["k_step"]["frames"] == 9 + 3 * 20  # 50 frames: horizons from 0, 20 and 29
    assert np.isfinite(rep.doc["horizons"]["k_step"]["rmse"]) and rep.doc["horizons"]["k_step"]["rmse"] < 1e-2


def test_a_joint_that_never_moves_has_no_nrmse(tmp_path, nominal_spec):
    eps, _ = simulate_arm(None, episodes=1, duration=0.5, seed=0)
    state = eps[0]["observation.state"].copy()
    state[:, 2] = 0.0  # j3 logged as constant
    write_dataset(tmp_path / "logs", from_arrays([{"observation.state": state, "action": eps[0]["action"]}], fps=100))
    doc = replay_logs(ReplayConfig(logs=str(tmp_path / "logs"), spec=str(nominal_spec))).doc
    j3 = doc["horizons"]["free_run"]["per_joint"]["j3"]
    assert j3["nrmse"] is None and "does not move" in j3["nrmse_reason"] and j3["rmse"] > 0
    assert doc["horizons"]["free_run"]["nrmse"] is not None  # the mean of the joints that move
    json.dumps(doc, allow_nan=False)


def _typo_spec(tmp_path):
    raw = spec_dict(None, model_file=str(ARM))
    raw["substep"] = raw.pop("substeps")
    path = tmp_path / "typo.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


def _bad_spec(tmp_path, **change):
    raw = spec_dict(None, model_file=str(ARM))
    raw["params"] = []
    raw["signals"] = {**raw["signals"], **change}
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(raw))
    return path


BAD = [
    (lambda t, logs, spec: [f"logs={t / 'nowhere'}", f"spec={spec}"], r"logs folder .*nowhere' does not exist"),
    (lambda t, logs, spec: [f"logs={logs}", f"spec={t / 'none.yaml'}"], r"spec file .*none.yaml' does not exist"),
    (lambda t, logs, spec: [f"logs={logs}"], r"spec= is required"),
    (lambda t, logs, spec: [f"logs={logs}", f"spec={spec}", "suite=held_out_robots"], r"not both"),
    (
        lambda t, logs, spec: [
            f"logs={logs}",
            f"spec={_bad_spec(t, qpos={'column': 'observation.stat', 'index': [0, 1, 2]})}",
        ],
        r"'signals.qpos.column': column 'observation.stat' is not in the log.*valid: action",
    ),
    (
        lambda t, logs, spec: [f"logs={logs}", f"spec={_bad_spec(t, ctrl={'column': 'action', 'index': [0, 1]})}"],
        r"'signals.ctrl.index' lists 2 columns; the model has nu=3",
    ),
    (
        lambda t, logs, spec: [
            f"logs={logs}",
            f"spec={_bad_spec(t, qvel={'column': 'observation.state', 'index': [3, 4, 9]})}",
        ],
        r"'signals.qvel.index': index 9 is out of range .* width 6",
    ),
    (lambda t, logs, spec: [f"logs={logs}", f"spec={spec}", "k=0"], r"k=0: must be in \[1, "),
    (lambda t, logs, spec: [f"logs={logs}", f"spec={spec}", "episodes=[0,7]"], r"episode 7 is not in .*valid: 0..1"),
    (lambda t, logs, spec: [f"logs={logs}", f"spec={spec}", "episodes=[]"], r"episodes=\[\] selects nothing"),
    (lambda t, logs, spec: [f"logs={logs}", f"spec={spec}", "kk=3"], r"unknown key 'kk'.*Did you mean 'k'"),
    (lambda t, logs, spec: [f"logs={logs}", "suite=held_out_robots"], r"feature 'observation.sim_state' missing"),
    (lambda t, logs, spec: [f"logs={logs}", f"spec={spec}", "commands=ctrl"], r"commands= applies to suite= replays"),
    (
        lambda t, logs, spec: [f"logs={logs}", f"spec={_typo_spec(t)}"],
        r"unknown spec field 'substep'.*Did you mean 'substeps'",
    ),
]


@pytest.mark.parametrize(
    "make_argv, pattern",
    BAD,
    ids=[
        "missing-logs",
        "missing-spec",
        "no-spec",
        "spec-and-suite",
        "column-not-in-log",
        "ctrl-width-vs-model",
        "index-out-of-range",
        "k-zero",
        "unknown-episode",
        "no-episode",
        "unknown-key",
        "suite-needs-sim-state",
        "commands-with-spec",
        "signal-map-typo",
    ],
)
def test_bad_input_one_line_exit_2_nothing_written(tmp_path, capsys, cases, nominal_spec, make_argv, pattern):
    out = tmp_path / "out"
    code = main(["replay", *make_argv(tmp_path, cases["None"], nominal_spec), f"out={out}"])
    err = capsys.readouterr().err
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    assert re.search(pattern, err), err
    assert not out.exists()


def test_a_calibration_spec_is_a_signal_map_with_more_fields(cases, tmp_path):
    """replay reads model, substeps and signals; a calibration spec's own fields are listed as ignored."""
    raw = spec_dict(None, model_file=str(ARM))
    raw["params"][0]["elements"] = ["no_such_joint"]  # calibration would refuse it; replay does not use it
    path = tmp_path / "calib.yaml"
    path.write_text(yaml.safe_dump(raw))
    doc = replay_logs(ReplayConfig(logs=str(cases["None"]), spec=str(path))).doc
    assert doc["spec"]["ignored"] == ["effects", "holdout", "horizon", "params"]
    assert doc["spec"]["substeps"] == 5 and set(doc["spec"]["signals"]) == {"qpos", "qvel", "ctrl", "inputs"}
    assert any("free parameters keep the model's values" in n for n in doc["notes"])


def test_replay_is_the_base_layer_it_never_imports_calibrate():
    """bench.replay is what bench.calibrate builds on: no module of it imports bench.calibrate."""
    import ast
    from pathlib import Path

    import bench.replay

    for path in sorted(Path(bench.replay.__file__).parent.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom)
                else []
            )
            assert not any(n == "bench.calibrate" or n.startswith("bench.calibrate.") for n in names), (
                f"{path.name} imports {names}"
            )


def test_help_names_every_key(capsys):
    assert main(["replay", "--help"]) == 0
    text = capsys.readouterr().out
    for key in ("logs", "spec", "suite", "commands", "k", "episodes", "out", "plot", "threads"):
        assert re.search(rf"^  {key}[\s=]", text, re.M), key  # `k=10`: the key with its default


@pytest.fixture(scope="module")
def robosuite_rec(tmp_path_factory):
    """`bench run record=` logs of Panda Lift: one nominal episode, one with 3x heavier links (~5 s)."""
    tmp = tmp_path_factory.mktemp("rec")
    return recorded(tmp, "robots=[Panda]", "episodes=1", "horizon=30", "workers=1", "perturb.link_mass=[3]")


def _by_condition(doc):
    return {r["condition"]: r for r in doc["per_episode"]}


@pytest.mark.parametrize("commands", ["ctrl", "action"])
def test_robosuite_recording_replays_in_the_nominal_env(robosuite_rec, commands):
    """Nominal episodes replay exactly, a heavier-link episode does not, with either kind of command."""
    doc = replay_logs(ReplayConfig(logs=str(robosuite_rec), suite="held_out_robots", k=5, commands=commands)).doc
    assert doc["commands"] == commands
    assert doc["backend"] == (
        "held_out_robots ctrl, mujoco.rollout (1 thread)" if commands == "ctrl" else "held_out_robots step loop"
    )
    assert "robot0_joint1" in doc["joints"] and "cube_joint0.z" in doc["joints"]
    by = _by_condition(doc)
    assert set(by) == {"nominal", "link_mass=3"}
    for h in HORIZONS:
        assert by["nominal"][f"{h}_nrmse"] < 1e-4, h  # the same simulator: float32 rounding of the log only
    assert by["link_mass=3"]["k_step_nrmse"] > 0.05 and by["link_mass=3"]["free_run_nrmse"] > 0.1
    json.dumps(doc, allow_nan=False)


def test_ctrl_is_the_default_and_threads_do_not_change_it(robosuite_rec):
    one = replay_logs(ReplayConfig(logs=str(robosuite_rec), suite="held_out_robots", k=5)).doc
    two = replay_logs(ReplayConfig(logs=str(robosuite_rec), suite="held_out_robots", k=5, threads=2)).doc
    assert one["commands"] == two["commands"] == "ctrl"
    # 25 physics steps per frame; 2 episodes x (29 one-step + 6 k-step segments of 5 + 29 free-run frames)
    assert one["sim_steps"] == two["sim_steps"] == 25 * 2 * (29 + 30 + 29)
    assert one["per_episode"] == two["per_episode"]


def test_recording_logs_ctrl_that_reproduce_the_physics(robosuite_rec):
    """`action.ctrl` holds every physics step's ctrl: mj_step with them from a logged state reaches the next one."""
    from bench.logs import read_dataset
    from bench.protocols import registry

    ds = read_dataset(robosuite_rec)
    feature = ds.features["action.ctrl"]
    assert feature["shape"] == [25 * 9]
    assert feature["names"][:2] == ["robot0_torq_j1@0", "robot0_torq_j2@0"] and feature["names"][-1].endswith("@24")
    suite = registry.make_suite("held_out_robots")
    cell = next(c for c in suite.all_cells() if c.robot == "Panda")
    env = suite.make_env(cell, 30)
    try:
        m = env.mujoco.model
        d = mujoco.MjData(m)
        ep = next(e for e in ds.episodes if e.meta["condition"] == "nominal")
        state, ctrl = ep.data["observation.sim_state"].astype(np.float64), ep.data["action.ctrl"].astype(np.float64)
        worst = 0.0
        for t in range(len(state) - 1):
            d.qpos[:], d.qvel[:] = state[t, : m.nq], state[t, m.nq :]
            for u in ctrl[t].reshape(25, m.nu):
                d.ctrl[:] = u
                mujoco.mj_step(m, d)
            worst = max(worst, float(np.abs(d.qpos - state[t + 1, : m.nq]).max()))
        assert worst < 1e-4  # float32 rounding of the logged states and commands only
    finally:
        env.close()


def test_suite_replay_bad_commands(robosuite_rec, tmp_path, capsys):
    from bench.logs import read_dataset

    ds = read_dataset(robosuite_rec)
    names = ds.features["action.ctrl"]["names"]
    for ep in ds.episodes:  # the same log, without the commands feature
        del ep.data["action.ctrl"]
    del ds.features["action.ctrl"]
    plain = write_dataset(tmp_path / "plain", ds)
    renamed = read_dataset(robosuite_rec)
    renamed.features["action.ctrl"]["names"] = ["motor" + n for n in names]
    renamed = write_dataset(tmp_path / "renamed", renamed)
    cases = [
        (
            [f"logs={robosuite_rec}", "suite=held_out_robots", "commands=torque"],
            r"commands is 'torque'; valid: ctrl, action",
        ),
        (
            [f"logs={plain}", "suite=held_out_robots", "commands=ctrl"],
            r"feature 'action.ctrl' missing.*commands=action",
        ),
        (
            [f"logs={renamed}", "suite=held_out_robots"],
            r"'action.ctrl' element 0 is 'motorrobot0_torq_j1@0', but input 0 of the model is 'robot0_torq_j1'",
        ),
    ]
    for argv, pattern in cases:
        out = tmp_path / "out"
        assert main(["replay", *argv, f"out={out}"]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and re.search(pattern, err), err
        assert not out.exists()
    doc = replay_logs(ReplayConfig(logs=str(plain), suite="held_out_robots", k=5)).doc  # falls back to the action loop
    assert doc["commands"] == "action"


def test_metaworld_recording_replays_batched_with_its_mocap_inputs(tmp_path):
    """Meta-World drives a mocap body: `action.ctrl` holds ctrl and the mocap pose of every physics step."""
    from bench.logs import read_dataset

    keys = ["suite=held_out_envs", "tasks=[reach-v3]", "episodes=1", "horizon=40", "workers=1"]
    rec = recorded(tmp_path, *keys, "perturb.link_mass=[3]")
    ds = read_dataset(rec)
    names = ds.features["action.ctrl"]["names"]
    assert names[:4] == ["actuator0@0", "actuator1@0", "mocap.mocap_x@0", "mocap.mocap_y@0"]
    assert ds.features["action.ctrl"]["shape"] == [5 * 9]  # frame_skip 5 x (2 ctrl + 3 pos + 4 quat)
    assert {ep.meta["ctrl_spec"] for ep in ds.episodes} == {
        int(mujoco.mjtState.mjSTATE_CTRL | mujoco.mjtState.mjSTATE_MOCAP_POS | mujoco.mjtState.mjSTATE_MOCAP_QUAT)
    }
    batched = replay_logs(ReplayConfig(logs=str(rec), suite="held_out_envs", k=5)).doc
    loop = replay_logs(ReplayConfig(logs=str(rec), suite="held_out_envs", k=5, commands="action")).doc
    assert batched["commands"] == "ctrl" and loop["commands"] == "action"
    for doc in (batched, loop):
        by = _by_condition(doc)
        for h in HORIZONS:
            assert by["nominal"][f"{h}_nrmse"] < 1e-3, (doc["commands"], h)
        assert by["link_mass=3"]["k_step_nrmse"] > 0.01 and by["link_mass=3"]["free_run_nrmse"] > 0.05
    one = {h: _by_condition(batched)["link_mass=3"][f"{h}_nrmse"] for h in ("one_step", "free_run")}
    other = {h: _by_condition(loop)["link_mass=3"][f"{h}_nrmse"] for h in ("one_step", "free_run")}
    assert one == pytest.approx(other, rel=1e-3)  # the mocap "controller" has no feedback: both replay the same


def test_recordings_from_several_scenes_replay_batched_per_model(tmp_path):
    """Two robosuite scenes (two models, same joints) in one log: one rollout per model, both replay exactly."""
    keys = ["suite=held_out_scenes", "envs=[nominal,table_up_12cm]", "episodes=1", "horizon=20", "workers=1"]
    rec = recorded(tmp_path, *keys)
    doc = replay_logs(ReplayConfig(logs=str(rec), suite="held_out_scenes", k=5, threads=2)).doc
    assert doc["commands"] == "ctrl" and len(doc["per_episode"]) == 2
    for row in doc["per_episode"]:  # a wrong model (the other scene's table) would put the cube elsewhere
        for h in HORIZONS:
            assert row[f"{h}_nrmse"] < 1e-4, (row, h)
    assert {row["env"] for row in doc["per_episode"]} == {"nominal", "table_up_12cm"}
