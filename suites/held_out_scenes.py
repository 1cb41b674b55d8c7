"""held_out_scenes: BridgeData-style transfer to scenes the policy never saw (robot and task fixed).

Task:
    robosuite `Lift` (pick the cube up) with the Panda arm; only the scene changes:
    table height, table size, table friction and the cube's spawn region.
Scene parameters (nominal = robosuite's Lift defaults):
    table_height    table-top height, m                      (nominal 0.80)
    table_size      table length x width, m (0.05 m thick)   (nominal 0.8 x 0.8; the robot
                    stays at the table's edge, so size moves the cube relative to the robot)
    table_friction  sliding friction of the table            (nominal 1.0)
    spawn_x/spawn_y cube spawn range, m from the table centre (nominal -0.03..0.03 each;
                    +x is away from the robot)
    In every scene (nominal included) the table's collision geom has MuJoCo contact
    priority 1, so the table's friction governs cube-table contacts; without it MuJoCo
    takes max(table, cube) = 1.0 and any smoother table would be inert. At 1.0 the
    cube-table contact is as in stock robosuite.
Split (declared region; every seen scene lies inside it, every unseen scene outside it
on at least one parameter, with spawn regions that do not overlap the seen square):
    seen region: height 0.76..0.84 m, size 0.7..0.9 m, friction 0.7..1.5,
                 spawn inside |x|, |y| <= 0.06 m
    seen   = nominal; table_up_4cm (0.84 m); table_down_4cm (0.76 m);
             table_small (0.7 x 0.7); table_smooth (friction 0.7);
             spawn_shift (x, y in 0.00..0.06)
    unseen = table_up_12cm (0.92 m); table_down_12cm (0.68 m);
             table_large (1.0 x 1.0: the cube 0.1 m farther from the robot);
             table_slippery (friction 0.2); spawn_far (x in 0.07..0.13, away from the
             robot); spawn_side (y in -0.13..-0.07)
    Cells: task = "Lift", robot = "Panda", env = scene name; cell.options = the scene's
    parameters. Select scenes with `envs=[nominal,spawn_far]`.
Observation / Action:
    as held_out_robots (suites/lift.py): 18 embodiment-agnostic numbers; 7-D OSC
    delta action. Cameras as held_out_robots (`obs=rgb|state+rgb`, `cameras=`, `image_size=`;
    default rgb.agentview and rgb.robot0_eye_in_hand).
Conditions:
    nominal; perturbations via `perturb.*` act on the MuJoCo model; visual axes on the images.
Success:
    success_once = the cube was lifted 4 cm above *this scene's* table top at any step;
    success_at_end = still lifted at the last step (250 steps, 20 Hz).
Metric:
    success rate per scene with Wilson intervals; mean over seen and unseen scenes with
    a stratified bootstrap interval; transfer gap = seen - unseen.
"""

from __future__ import annotations

from typing import Any

from bench.protocols.suite import Cell, declared_scene, scene_cells
from suites.lift import LiftSuite, make_env

NOMINAL: dict[str, Any] = {
    "table_height": 0.80,
    "table_size": [0.8, 0.8],
    "table_friction": 1.0,
    "spawn_x": [-0.03, 0.03],
    "spawn_y": [-0.03, 0.03],
}
TABLE_THICKNESS = 0.05  # m, robosuite's Lift default

# the seen region of scene-parameter space: closed intervals, spawn as a square around the centre
SEEN_REGION: dict[str, Any] = {
    "table_height": (0.76, 0.84),
    "table_size": (0.7, 0.9),
    "table_friction": (0.7, 1.5),
    "spawn_half_width": 0.06,
}

SEEN_SCENES: dict[str, dict[str, Any]] = {
    "nominal": {},
    "table_up_4cm": {"table_height": 0.84},
    "table_down_4cm": {"table_height": 0.76},
    "table_small": {"table_size": [0.7, 0.7]},
    "table_smooth": {"table_friction": 0.7},
    "spawn_shift": {"spawn_x": [0.0, 0.06], "spawn_y": [0.0, 0.06]},
}
UNSEEN_SCENES: dict[str, dict[str, Any]] = {
    "table_up_12cm": {"table_height": 0.92},
    "table_down_12cm": {"table_height": 0.68},
    "table_large": {"table_size": [1.0, 1.0]},
    "table_slippery": {"table_friction": 0.2},
    "spawn_far": {"spawn_x": [0.07, 0.13]},
    "spawn_side": {"spawn_y": [-0.13, -0.07]},
}


def scene_params(name: str) -> dict[str, Any]:
    """Full parameters of a declared scene (nominal values where the scene does not change them)."""
    return declared_scene(name, NOMINAL, SEEN_SCENES, UNSEEN_SCENES)


def region_relation(params: dict[str, Any]) -> str:
    """Where a scene lies relative to `SEEN_REGION`: "inside", "outside" or "straddles".

    "outside" means at least one scalar parameter is out of its seen interval, or the
    spawn rectangle does not overlap the seen spawn square at all; "straddles" (a spawn
    region partly in the seen square, everything else inside) makes a split ambiguous.
    """

    def within(v: float, lo_hi: tuple[float, float]) -> bool:
        return lo_hi[0] - 1e-9 <= v <= lo_hi[1] + 1e-9

    r = SEEN_REGION
    scalars_in = (
        within(params["table_height"], r["table_height"])
        and all(within(s, r["table_size"]) for s in params["table_size"])
        and within(params["table_friction"], r["table_friction"])
    )
    w = r["spawn_half_width"]
    (x0, x1), (y0, y1) = params["spawn_x"], params["spawn_y"]
    spawn_in = -w - 1e-9 <= x0 and x1 <= w + 1e-9 and -w - 1e-9 <= y0 and y1 <= w + 1e-9
    spawn_out = x1 < -w or x0 > w or y1 < -w or y0 > w
    if not scalars_in or spawn_out:
        return "outside"
    return "inside" if spawn_in else "straddles"


def env_kwargs(params: dict[str, Any]) -> dict[str, Any]:
    """robosuite Lift kwargs (plus `bench.sims.robosuite.SCENE_KEYS`) that build a scene."""
    sx, sy = params["table_size"]
    return {
        "table_full_size": (float(sx), float(sy), TABLE_THICKNESS),
        "table_friction": (float(params["table_friction"]), 5e-3, 1e-4),
        "table_offset": (0.0, 0.0, float(params["table_height"])),
        "table_contact_priority": 1,
        "placement_x_range": tuple(float(v) for v in params["spawn_x"]),
        "placement_y_range": tuple(float(v) for v in params["spawn_y"]),
    }


class HeldOutScenes(LiftSuite):
    """Panda Lift in 12 robosuite scenes (table height/size/friction, spawn region); 6 seen, 6 held out."""

    name = "held_out_scenes"
    version = "1"
    manifest = {"envs": {"seen": list(SEEN_SCENES), "unseen": list(UNSEEN_SCENES)}}

    def all_cells(self) -> list[Cell]:
        return scene_cells(self.name, "Lift", "Panda", SEEN_SCENES, UNSEEN_SCENES, scene_params)

    def make_env(self, cell: Cell, horizon: int):
        return make_env(
            cell.task,
            cell.robot,
            horizon,
            env_kwargs(cell.options or scene_params(cell.env)),
            options=self.options,
            where=cell.key,
        )
