"""lerobot policies for bench: prepare a bench recording for lerobot training; serve a trained policy.

Runs in lerobot's own venv (`bash .ci/lerobot-venv.sh`), never in bench's: lerobot pins its own
torch and brings pandas. It imports only bench's wire code (`bench.remote.serving`, numpy +
msgpack + websockets) from this checkout. The recipe (docs/remote-policies.md, "lerobot"):

    bench run suite=held_out_robots policy=scripted splits=[seen] episodes=20 record=demos
    PY=.lerobot-venv/bin/python
    $PY baselines/lerobot_adapter.py prepare demos demos_lerobot
    $PY -m lerobot.scripts.lerobot_train --dataset.repo_id=bench/demos --dataset.root=demos_lerobot \\
        --policy.type=act --policy.device=cpu --policy.push_to_hub=false --output_dir=act_run ...
    $PY baselines/lerobot_adapter.py serve act_run/checkpoints/last/pretrained_model --port 8000
    bench run suite=held_out_robots policy=remote port=8000 \\
        obs_map=[observation.state:state,observation.environment_state:state.object_pos+state.object_quat+state.gripper_to_object]

prepare SRC DST [--env-fields a,b,...]
    lerobot's ACT and diffusion policies need an image or an environment state among their inputs;
    bench's state-only recordings have neither. This adds `observation.environment_state` (the
    named fields of `observation.state` that describe the world, default the object's pose and
    the gripper-to-object vector) with lerobot's own dataset tool (`modify_features`), and drops
    bench's replay-only features (`observation.sim_state`, `action.ctrl`).

serve POLICY_DIR [--host 127.0.0.1] [--port 8000] [--device cpu]
    Loads a trained policy (`PreTrainedPolicy.from_pretrained` + its saved pre/post-processors)
    and answers each observation with `predict_action_chunk`: {"actions": (T, A)} in the
    dataset's units. Input keys are the policy's `input_features` (lerobot's names: send them
    with the client's `obs_map=`); images are sent as uint8 H x W x 3 and converted here; a
    `task` string is passed on to language-conditioned policies. It speaks bench's `reset`
    extension: each episode resets the policy and seeds torch with the episode seed.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("HF_HUB_OFFLINE", "1")  # a local folder must never turn into a hub download
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # bench's wire code, from this checkout

import numpy as np  # noqa: E402

from bench.api.serving import (  # noqa: E402
    RequestError,
    WebsocketServer,
    wire,  # noqa: E402
)

DEFAULT_ENV_FIELDS = ("object_pos", "object_quat", "gripper_to_object")
BENCH_ONLY = ("observation.sim_state", "action.ctrl")


def fail(message: str) -> None:
    print(f"error: {message}", file=sys.stderr)
    sys.exit(2)


def _dataset(root: str) -> Any:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    if not os.path.isfile(os.path.join(root, "meta", "info.json")):  # else lerobot would go to the hub
        fail(f"{root}: not a LeRobot dataset folder (meta/info.json is missing)")
    return LeRobotDataset(f"bench/{Path(root).name}", root=root)


def _select(names: list[str], fields: list[str], flag: str) -> list[int]:
    """Indices of the named state fields (a field `f` names `f` or `f_0`, `f_1`, ...), in the order given."""
    missing = [f for f in fields if not any(n == f or n.startswith(f + "_") for n in names)]
    if missing or not fields:
        fail(f"{flag}: {missing or fields} not in observation.state (names: {', '.join(names)})")
    return [i for f in fields for i, n in enumerate(names) if n == f or n.startswith(f + "_")]


def prepare(src: str, dst: str, env_fields: list[str], state_fields: list[str] | None = None) -> None:
    """DST = SRC + observation.environment_state (named state fields) - bench's replay-only features; with
    `state_fields`, observation.state keeps only those fields (e.g. ALOHA's agent_pos, as lerobot-eval sends it)."""
    from lerobot.datasets.dataset_tools import modify_features

    if os.path.exists(dst):
        fail(f"{dst} exists; give a new folder (nothing is overwritten)")
    ds = _dataset(src)
    names = list(ds.meta.features["observation.state"]["names"] or [])
    idx = _select(names, env_fields, "--env-fields") if env_fields else []
    keep = _select(names, state_fields, "--state-fields") if state_fields else None

    # the state of every frame, in the order lerobot's tool rewrites them (data files sorted, rows in order)
    import pyarrow.parquet as pq  # pyarrow: loaded only when a dataset is prepared

    files = sorted((Path(src) / "data").glob("*/*.parquet"))
    state = np.concatenate(
        [
            np.stack(pq.read_table(f, columns=["observation.state"]).column(0).to_numpy(zero_copy_only=False))
            for f in files
        ]
    ).astype(np.float32)

    def rows(columns: list[int]) -> np.ndarray:  # one vector per frame (an object array: lerobot's tool slices it)
        out = np.empty(len(state), dtype=object)
        out[:] = list(state[:, columns])
        return out

    info = {"dtype": "float32", "shape": [len(idx)], "names": [names[i] for i in idx]}
    add: dict[str, Any] = {"observation.environment_state": (rows(idx), info)} if idx else {}
    drop = [f for f in BENCH_ONLY if f in ds.meta.features]
    if keep is not None:  # lerobot cannot replace a feature in one pass: select into a new one, then rename
        state_info = {"dtype": "float32", "shape": [len(keep)], "names": [names[i] for i in keep]}
        add["observation.state_selected"] = (rows(keep), state_info)
    tmp = f"{dst}.partial"
    out = modify_features(
        ds,
        add_features=add,
        remove_features=(drop + ["observation.state"] if keep is not None else drop) or None,
        output_dir=tmp if keep is not None else dst,
        repo_id=f"bench/{Path(dst).name}",
    )
    if keep is not None:
        out = modify_features(
            out,
            add_features={"observation.state": (rows(keep), state_info)},
            remove_features="observation.state_selected",
            output_dir=dst,
            repo_id=f"bench/{Path(dst).name}",
        )
        shutil.rmtree(tmp)
    state_note = f"; observation.state = {', '.join(names[i] for i in keep)}" if keep is not None else ""
    print(
        f"wrote {dst}: {out.num_episodes} episodes, {len(out)} frames; observation.environment_state = "
        f"{', '.join(info['names']) or '(none)'}{state_note}; dropped {', '.join(drop) or 'nothing'}"
    )


def feature_mismatch(inputs: dict[str, Any], sends: Any) -> str | None:
    """One line naming the first input feature of the policy that the client will not send, or not in its
    shape (images: uint8 H x W x 3 for a C x H x W feature), or None. `sends` is what a bench client announces
    in its preflight check ({wire key: {"shape", "dtype"}}); a client that announces nothing is not checked."""
    if not isinstance(sends, dict) or not sends:
        return None
    for key, feat in inputs.items():
        shape = [int(n) for n in feat.shape]
        if feat.type.name == "VISUAL":
            want, what = [shape[1], shape[2], shape[0]], "a uint8 image"
        else:
            want, what = shape, "a float vector"
        got = sends.get(key)
        if not isinstance(got, dict):
            return (
                f"the policy's input feature {key!r} ({what} of shape {want}) is not in the observation bench sends "
                f"({', '.join(sorted(sends))}); map it with obs_map=[{key}:SOURCE]"
            )
        if list(got.get("shape") or []) != want or (feat.type.name == "VISUAL" and got.get("dtype") != "uint8"):
            return (
                f"the policy's input feature {key!r} is {what} of shape {want}, but bench sends "
                f"{got.get('dtype')} {got.get('shape')} under that name (check obs_map=, obs=, image_size=)"
            )
    return None


class LerobotSession:
    """One connection: observations -> lerobot batch -> predict_action_chunk -> (T, A) numpy."""

    def __init__(self, served: Served):
        self.s = served

    def handle(self, msg: dict[str, Any]) -> dict[str, Any]:
        import torch

        if wire.CONTROL in msg:
            body = msg[wire.CONTROL]
            op = body.get("op") if isinstance(body, dict) else None
            if op == "reset":
                seed = body.get("seed")
                if not isinstance(seed, int) or seed < 0:
                    raise RequestError(f"reset: seed={seed!r} must be a non-negative integer")
                self.s.policy.reset()
                torch.manual_seed(seed)
            elif op == "check":
                problem = feature_mismatch(self.s.inputs, body.get("sends"))
                if problem:
                    raise RequestError(problem)
            else:
                raise RequestError(f"control op {op!r} is unknown; valid: reset, check")
            return {wire.CONTROL: {"ok": True, "op": op}}
        t0 = time.perf_counter()
        batch: dict[str, Any] = {}
        for key, feat in self.s.inputs.items():
            if key not in msg:
                raise RequestError(
                    f"the observation lacks {key!r} (this policy's inputs: {list(self.s.inputs)}; "
                    f"got {sorted(msg)[:12]}); map it with the client's obs_map="
                )
            arr = np.asarray(msg[key])
            shape = tuple(feat.shape)
            if feat.type.name == "VISUAL":  # uint8 H x W x C -> float C x H x W in [0, 1], as lerobot's datasets give
                if arr.ndim != 3 or arr.dtype != np.uint8 or (arr.shape[2], *arr.shape[:2]) != shape:
                    raise RequestError(
                        f"obs[{key!r}] is {list(arr.shape)} {arr.dtype}; expected uint8 "
                        f"{[shape[1], shape[2], shape[0]]} (H x W x C)"
                    )
                tensor = torch.from_numpy(arr).permute(2, 0, 1).float() / 255.0
            else:
                if arr.shape != shape or arr.dtype.kind not in "biuf":
                    raise RequestError(f"obs[{key!r}] is {list(arr.shape)} {arr.dtype}; expected {list(shape)} float")
                tensor = torch.from_numpy(arr.astype(np.float32))
            batch[key] = tensor.unsqueeze(0).to(self.s.device)
        if isinstance(msg.get("task"), str):
            batch["task"] = [msg["task"]]
        with torch.inference_mode():
            chunk = self.s.policy.predict_action_chunk(self.s.pre(batch))
            chunk = self.s.post(chunk)
        actions = chunk[0].detach().cpu().numpy().astype(np.float32)
        return {wire.ACTIONS: actions, "server_timing": {"infer_ms": (time.perf_counter() - t0) * 1000.0}}

    def close(self) -> None:
        pass


class Served:
    """A trained lerobot policy with its processors, loaded once and shared by the connections."""

    def __init__(self, path: str, device: str):
        import torch
        from lerobot.configs.policies import PreTrainedConfig
        from lerobot.policies.factory import get_policy_class, make_pre_post_processors

        if not os.path.isfile(os.path.join(path, "config.json")):
            fail(
                f"{path}: not a trained lerobot policy (config.json missing); give .../checkpoints/last/"
                "pretrained_model"
            )
        torch.set_num_threads(max(1, int(os.environ.get("BENCH_TORCH_THREADS", "1"))))
        cfg = PreTrainedConfig.from_pretrained(path)
        cfg.device = device
        self.policy = get_policy_class(cfg.type).from_pretrained(path, config=cfg)
        self.policy.to(device).eval()
        self.pre, self.post = make_pre_post_processors(
            cfg, pretrained_path=path, preprocessor_overrides={"device_processor": {"device": device}}
        )
        self.inputs = dict(cfg.input_features)
        self.device, self.type = device, cfg.type
        weights = Path(path) / "model.safetensors"
        self.sha256 = hashlib.sha256(weights.read_bytes()).hexdigest() if weights.is_file() else None
        self.metadata = {
            "bench": {
                "protocol": wire.PROTOCOL,
                "policy": f"lerobot:{cfg.type}",
                "checkpoint": path,
                "checkpoint_sha256": self.sha256,
                "obs_keys": list(self.inputs),
            },
            "lerobot": {
                "type": cfg.type,
                "input_features": {k: list(v.shape) for k, v in self.inputs.items()},
                "action_dim": int(cfg.output_features["action"].shape[0]),
            },
        }


def serve(path: str, host: str, port: int, device: str) -> None:
    served = Served(path, device)

    def log(text: str) -> None:
        print(f"[{time.strftime('%H:%M:%S')}] {text}", file=sys.stderr, flush=True)

    server = WebsocketServer(
        lambda: LerobotSession(served),
        served.metadata,
        host,
        port,
        log=log,
        failure_prefix=f"lerobot {served.type} failed",
    )
    try:
        bound = server.bind()
    except OSError as exc:
        fail(f"--host {host} --port {port}: cannot listen there ({exc.strerror}); pick another port (0 = any)")

    where = f"[{host}]" if ":" in host else host
    server.serve_until_stopped(
        f"lerobot adapter: {served.type} policy {path} on ws://{where}:{bound} (inputs: "
        f"{', '.join(served.inputs)}); Ctrl-C stops",
        "lerobot adapter",
    )


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="lerobot_adapter.py", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("prepare", help="bench recording -> lerobot training set (adds observation.environment_state)")
    p.add_argument("src")
    p.add_argument("dst")
    p.add_argument(
        "--env-fields",
        default=",".join(DEFAULT_ENV_FIELDS),
        help="state fields that form observation.environment_state (comma-separated; '' = none, for image policies)",
    )
    p.add_argument(
        "--state-fields",
        default="",
        help="keep only these state fields in observation.state (comma-separated; default: all)",
    )
    s = sub.add_parser("serve", help="serve a trained lerobot policy over the remote-policy protocol")
    s.add_argument("policy_dir")
    s.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    s.add_argument("--port", type=int, default=8000, help="port (0 = any free one, printed)")
    s.add_argument("--device", default="cpu")
    args = parser.parse_args(argv)
    if args.command == "prepare":
        prepare(
            args.src,
            args.dst,
            [f.strip() for f in args.env_fields.split(",") if f.strip()],
            [f.strip() for f in args.state_fields.split(",") if f.strip()] or None,
        )
    else:
        if not 0 <= args.port <= 65535:
            fail(f"--port {args.port}: must be in [0, 65535]")
        serve(args.policy_dir, args.host, args.port, args.device)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
