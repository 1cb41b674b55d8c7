"""`bench replay`: open-loop replay of logged commands in the simulator, per joint and per horizon.

Each logged episode is replayed from its own logged states under its logged commands, and the
simulated joint positions are compared with the logged ones at three horizons:

- `one_step`: re-initialised from the logged state every frame, one frame ahead;
- `k_step`: re-initialised every k frames, k frames ahead (truncated horizons: no drift);
- `free_run`: initialised once at the episode's first frame, to its end.

Reported per joint: RMSE (in the joint's units) and NRMSE (RMSE / std of the logged position over
the replayed frames), plus the mean over joints, per episode and over all of them.

Two backends:

- **MJCF** (`spec=`): a signal map (`bench.replay.spec`; a calibration spec is one, with more
  fields) names the model and where qpos, qvel and ctrl live in the log. The model is replayed
  *as given* (a calibration spec's free parameters and effects are not used); all segments of one
  horizon run in one batched `mujoco.rollout` call (`bench.replay.simulate`,
  `bench.replay.metrics.horizon_errors`).
- **suite** (`suite=`): datasets written by `bench run ... record=DIR` carry the MuJoCo state
  before every step (`observation.sim_state`), the policy's action and, for robosuite and
  Meta-World envs, the MuJoCo inputs of every physics step (`action.ctrl`: actuator commands, and
  Meta-World's mocap pose). Two ways to replay them in the suite's nominal env (`commands=`):
  - `ctrl` (default when logged): the logged inputs, re-applied physics step by physics step
    from the logged states, all segments of a horizon batched in `mujoco.rollout`. This replays
    the physics alone: what the controller did is taken from the log.
  - `action`: the logged policy actions through the env's own controller (robosuite's OSC is
    Python), in a Python step loop: set the state at each segment start, `env.step` the actions.
    This also replays the controller, so a gap in what it computes shows up too.

This package is the base layer of Real2Sim: `spec` (the signal map), `data` (the recording),
`simulate` (batched rollouts of model variants from logged states) and `metrics` (per-joint errors
per horizon) are what `bench.calibrate` builds on; nothing here imports `bench.calibrate`.
"""

from __future__ import annotations

from bench.replay.common import COMMANDS, CTRL, SCHEMA, Replay, ReplayConfig, check_config, summarise
from bench.replay.mjcf import replay_mjcf
from bench.replay.suite_env import SuiteLogs, load_suite_logs, replay_actions, replay_ctrl, replay_suite, suite_segments

__all__ = [
    "COMMANDS",
    "CTRL",
    "SCHEMA",
    "Replay",
    "ReplayConfig",
    "SuiteLogs",
    "load_suite_logs",
    "replay_actions",
    "replay_ctrl",
    "replay_mjcf",
    "replay_logs",
    "replay_suite",
    "suite_segments",
    "summarise",
]


def replay_logs(cfg: ReplayConfig) -> Replay:
    """Validate the config and replay with the backend it names (`suite=` or `spec=`)."""
    check_config(cfg)
    if cfg.suite:
        return replay_suite(cfg)
    return replay_mjcf(cfg)
