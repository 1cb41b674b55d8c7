"""`policy=checkpoint checkpoint=PATH`: a torch policy loaded from weights plus a JSON spec, never unpickled.

Format (two files side by side):
    PATH        the weights: `NAME.safetensors` (preferred), or `NAME.pt` read with
                `torch.load(weights_only=True)` (a flat dict name -> tensor); nothing
                else is accepted, so an untrusted file cannot run code.
    NAME.json   the policy spec, PATH with its suffix replaced by `.json`
                (`bc/policy.safetensors` -> `bc/policy.json`):

    {
      "schema": "bench.policy/1",
      "architecture": "mlp",                          # a name in baselines.architectures
      "kwargs": {"hidden": [256, 256], "activation": "relu"},
      "obs_names": [["eef_pos", 3], ["eef_quat_rel", 4], ...],   # the suite's env.obs_names
      "action_names": ["dx", "dy", ...],                          # the suite's env.action_names
      "obs_dim": 18, "action_dim": 7,                 # optional; must equal the sums of the names
      "normalization": {                              # optional; absent = identity
        "obs":    {"mean": [...obs_dim], "std": [...obs_dim]},
        "action": {"mean": [...action_dim], "std": [...action_dim]}
      },
      "clip_actions": true,                           # optional (default true): clip to the env's bounds
      "chunk": 1,                                     # optional (default 1): actions per answer; the model
                                                      #   outputs chunk x action_dim numbers, row by row
      "meta": {...}                                   # optional, free-form (training set, suite, seed ...)
    }

Inference: `a = model((obs - obs_mean) / obs_std) * act_std + act_mean`, clipped to the
env's action bounds, on CPU with one torch thread per worker. The model must be
deterministic (`reset(seed)` has nothing to reseed).

`save_checkpoint` writes both files and also embeds the spec in the safetensors
header metadata (key `bench.policy_spec`), so the checkpoint sha256 that every
record carries covers the normalisation and architecture too; at load a
sidecar that differs from the embedded copy is an error, and a missing sidecar
falls back to the embedded copy. At load, the spec's obs/action names must equal
the env's (ConfigError otherwise): a policy trained on another observation
layout would silently read the wrong numbers.

Bad input — missing file, malformed spec, unknown architecture, weights that do
not fit the architecture — is a one-line SpecError/ConfigError (exit 2), raised
by the plugin's `preflight` before `bench run` starts any worker.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from baselines.architectures import rowwise
from bench.api import ConfigError, SpecError, valid_choices
from bench.api.data import sha256_file, write_bytes_atomic, write_text_atomic
from bench.protocols import STATE, Obs, PolicyContext, PolicyIdentity, PolicyPlugin

SPEC_SCHEMA = "bench.policy/1"
METADATA_KEY = "bench.policy_spec"
WEIGHT_SUFFIXES = (".safetensors", ".pt")
SPEC_KEYS = (
    "schema",
    "architecture",
    "kwargs",
    "obs_names",
    "action_names",
    "obs_dim",
    "action_dim",
    "normalization",
    "clip_actions",
    "chunk",
    "meta",
)
MAX_CHUNK = 1000


def spec_path(path: str | Path) -> Path:
    """The spec file beside the weights: PATH with its suffix replaced by `.json`."""
    return Path(path).with_suffix(".json")


def _canonical(spec: dict[str, Any]) -> str:
    return json.dumps(spec, sort_keys=True, separators=(",", ":"), allow_nan=False)


def _floats(value: Any, n: int, where: str) -> list[float]:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise SpecError(f"policy spec: {where} must be a list of {n} numbers, got {str(value)[:60]}") from None
    if arr.shape != (n,):
        raise SpecError(f"policy spec: {where} has shape {list(arr.shape)}; expected [{n}]")
    if not np.all(np.isfinite(arr)):
        raise SpecError(f"policy spec: {where} contains NaN or inf")
    return [float(x) for x in arr]


def normalize_spec(spec: Any, source: str = "policy spec") -> dict[str, Any]:
    """Check a spec dict and return it in canonical form (plain JSON types, dims filled in).

    Raises:
        SpecError: one line naming the bad field and what is valid.
    """
    from baselines.architectures import ARCHITECTURES

    if not isinstance(spec, dict):
        raise SpecError(f"{source}: must be a JSON object, got {type(spec).__name__}")
    for key in spec:
        if key not in SPEC_KEYS:
            raise SpecError(f"{source}: unknown field {key!r}; {valid_choices(key, SPEC_KEYS)}")
    schema = spec.get("schema", SPEC_SCHEMA)
    if schema != SPEC_SCHEMA:
        raise SpecError(f"{source}: schema={schema!r} is not supported; valid: {SPEC_SCHEMA}")
    for key in ("architecture", "obs_names", "action_names"):
        if key not in spec:
            raise SpecError(f"{source}: missing field {key!r} (required: architecture, obs_names, action_names)")
    arch = spec["architecture"]
    if arch not in ARCHITECTURES:
        valid = sorted(ARCHITECTURES)
        raise SpecError(f"{source}: architecture={arch!r} is not registered; {valid_choices(str(arch), valid)}")
    kwargs = spec.get("kwargs") or {}
    if not isinstance(kwargs, dict):
        raise SpecError(f"{source}: kwargs must be an object, got {type(kwargs).__name__}")
    try:
        obs_names: list[list[Any]] = [[str(n), int(w)] for n, w in spec["obs_names"]]
    except (TypeError, ValueError):
        raise SpecError(f"{source}: obs_names must be a list of [name, width] pairs") from None
    if not obs_names or any(w < 1 for _, w in obs_names):
        raise SpecError(f"{source}: obs_names must be non-empty with widths >= 1")
    action_names = spec["action_names"]
    if not isinstance(action_names, list) or not action_names or not all(isinstance(a, str) for a in action_names):
        raise SpecError(f"{source}: action_names must be a non-empty list of strings")
    obs_dim, action_dim = sum(w for _, w in obs_names), len(action_names)
    for key, want in (("obs_dim", obs_dim), ("action_dim", action_dim)):
        if key in spec and spec[key] != want:
            raise SpecError(f"{source}: {key}={spec[key]!r} but the names give {want}")
    out: dict[str, Any] = {
        "schema": SPEC_SCHEMA,
        "architecture": arch,
        "kwargs": json.loads(json.dumps(kwargs, default=_jsonable)),
        "obs_names": obs_names,
        "action_names": list(action_names),
        "obs_dim": obs_dim,
        "action_dim": action_dim,
    }
    norm = spec.get("normalization") or {}
    if not isinstance(norm, dict):
        raise SpecError(f"{source}: normalization must be an object with optional 'obs' and 'action'")
    norm_out = {}
    for side, n in (("obs", obs_dim), ("action", action_dim)):
        if side not in norm or norm[side] is None:
            continue
        entry = norm[side]
        if not isinstance(entry, dict) or set(entry) != {"mean", "std"}:
            raise SpecError(f"{source}: normalization.{side} must have exactly 'mean' and 'std'")
        mean = _floats(entry["mean"], n, f"normalization.{side}.mean")
        std = _floats(entry["std"], n, f"normalization.{side}.std")
        if min(std) <= 0:
            raise SpecError(f"{source}: normalization.{side}.std must be > 0 everywhere (min {min(std)})")
        norm_out[side] = {"mean": mean, "std": std}
    for side in norm:
        if side not in ("obs", "action"):
            raise SpecError(f"{source}: normalization.{side} is not valid; valid: obs, action")
    out["normalization"] = norm_out
    clip = spec.get("clip_actions", True)
    if not isinstance(clip, bool):
        raise SpecError(f"{source}: clip_actions must be true or false, got {clip!r}")
    out["clip_actions"] = clip
    if "chunk" in spec:
        chunk = spec["chunk"]
        if not isinstance(chunk, int) or isinstance(chunk, bool) or not 1 <= chunk <= MAX_CHUNK:
            raise SpecError(f"{source}: chunk={chunk!r} must be an integer in [1, {MAX_CHUNK}] (actions per answer)")
        out["chunk"] = chunk
    if "meta" in spec:
        meta = spec["meta"]
        if not isinstance(meta, dict):
            raise SpecError(f"{source}: meta must be an object")
        out["meta"] = json.loads(json.dumps(meta, default=_jsonable))
    return out


def _jsonable(x: Any) -> Any:
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, np.generic):
        return x.item()
    if hasattr(x, "tolist"):  # torch tensors
        return x.tolist()
    raise TypeError(f"{type(x).__name__} is not JSON serialisable")


def save_checkpoint(path: str | Path, model, spec: dict[str, Any]) -> Path:
    """Write `model`'s weights to PATH (.safetensors) and the spec beside it (PATH with .json).

    The weights must fit the spec's architecture (checked by loading them into a fresh
    build), so what is saved always loads. Returns the weights path.

    Args:
        path: destination, ending in `.safetensors`.
        model: an `nn.Module` built by `baselines.architectures.build` (or state-compatible).
        spec: the policy spec (see the module docstring); numpy arrays are fine for
            normalisation; `obs_dim`/`action_dim` are filled in from the names.
    """
    from baselines.architectures import build

    path = Path(path)
    if path.suffix != ".safetensors":
        raise ConfigError(f"save_checkpoint: path {str(path)!r} must end in .safetensors")
    spec = normalize_spec(spec)
    state = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    fresh = build(spec["architecture"], spec["obs_dim"], spec["action_dim"] * spec.get("chunk", 1), spec["kwargs"])
    _load_state(fresh, state, str(path))
    from safetensors.torch import save as to_bytes

    write_bytes_atomic(path, to_bytes(state, metadata={METADATA_KEY: _canonical(spec)}))
    write_text_atomic(spec_path(path), json.dumps(spec, indent=2) + "\n")
    return path


def _load_state(module, state: dict[str, Any], source: str) -> None:
    try:
        module.load_state_dict(state, strict=True)
    except RuntimeError as exc:
        lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
        detail = "; ".join(lines[1:3]) if len(lines) > 1 else lines[0] if lines else "mismatch"
        raise SpecError(f"{source}: weights do not fit the spec's architecture: {detail[:300]}") from None


def read_weights(path: str | Path) -> tuple[dict[str, Any], dict[str, str]]:
    """Tensors and header metadata of a `.safetensors` or weights-only `.pt` file (never unpickles code);
    a tensor holding NaN or infinity is refused, naming it (such a policy only ever acts NaN)."""
    tensors, meta = _read_weights(path)
    import torch

    for name, t in tensors.items():
        if torch.is_floating_point(t) and not bool(torch.isfinite(t).all()):
            raise SpecError(f"checkpoint={str(path)!r}: tensor {name!r} holds NaN or infinite values")
    return tensors, meta


def _read_weights(path: str | Path) -> tuple[dict[str, Any], dict[str, str]]:
    import torch

    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"checkpoint={str(path)!r}: no such file")
    if path.suffix not in WEIGHT_SUFFIXES:
        raise ConfigError(
            f"checkpoint={str(path)!r}: unsupported file type {path.suffix!r}; valid: "
            f"{', '.join(WEIGHT_SUFFIXES)} (pickled checkpoints are never loaded)"
        )
    if path.suffix == ".safetensors":
        from safetensors import safe_open

        try:
            with safe_open(str(path), framework="pt", device="cpu") as fh:
                meta = dict(fh.metadata() or {})
                tensors = {k: fh.get_tensor(k) for k in fh.keys()}
        except Exception as exc:  # SafetensorError, OSError: corrupt or truncated file
            raise SpecError(
                f"checkpoint={str(path)!r}: not a readable safetensors file "
                f"({type(exc).__name__}: {str(exc).splitlines()[0][:120] if str(exc) else ''})"
            ) from None
        return tensors, meta
    try:
        obj = torch.load(str(path), map_location="cpu", weights_only=True)
    except Exception as exc:  # UnpicklingError for anything that is not plain tensors
        raise SpecError(
            f"checkpoint={str(path)!r}: cannot be read with torch.load(weights_only=True) "
            f"({type(exc).__name__}: {str(exc).splitlines()[0][:120] if str(exc) else ''})"
        ) from None
    if isinstance(obj, dict) and isinstance(obj.get("state_dict"), dict):
        obj = obj["state_dict"]
    if not isinstance(obj, dict) or not all(isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in obj.items()):
        raise SpecError(f"checkpoint={str(path)!r}: expected a flat dict of name -> tensor (a state_dict)")
    return dict(obj), {}


def load_spec(path: str | Path, meta: dict[str, str] | None = None) -> dict[str, Any]:
    """The checked spec of the checkpoint at `path` (the sidecar, else the copy embedded in the weights)."""
    sidecar = spec_path(path)
    embedded = None
    if meta and METADATA_KEY in meta:
        try:
            embedded = normalize_spec(json.loads(meta[METADATA_KEY]), f"{path} (embedded spec)")
        except json.JSONDecodeError:
            raise SpecError(f"checkpoint={str(path)!r}: embedded spec is not valid JSON") from None
    if sidecar.is_file():
        try:
            raw = json.loads(sidecar.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise SpecError(f"{sidecar}: not valid JSON ({str(exc).splitlines()[0]})") from None
        spec = normalize_spec(raw, str(sidecar))
        if embedded is not None and _canonical(embedded) != _canonical(spec):
            diff = next((k for k in SPEC_KEYS if embedded.get(k) != spec.get(k)), "?")
            raise SpecError(
                f"{sidecar}: field {diff!r} differs from the spec embedded in {Path(path).name} at save "
                "time; the checkpoint sha256 would not identify this policy (re-save it)"
            )
        return spec
    if embedded is not None:
        return embedded
    raise SpecError(f"checkpoint={str(path)!r}: policy spec {sidecar} not found (see baselines.checkpoint docs)")


class CheckpointPolicy:
    """A deterministic torch policy: normalise the state -> model -> de-normalise action -> clip."""

    def __init__(self, model, spec: dict[str, Any], action_low=None, action_high=None, replan_every: int = 0):
        self.model, self.spec = model.eval(), spec
        self.chunk, self.replan_every = int(spec.get("chunk", 1)), int(replan_every)
        self.batch_key: Any = None  # set by load_policy: equal keys answer identically (bench serve batch=N)
        norm = spec.get("normalization", {})
        od, ad = spec["obs_dim"], spec["action_dim"]
        o, a = norm.get("obs"), norm.get("action")
        self.obs_mean = np.asarray(o["mean"] if o else np.zeros(od), np.float32)
        self.obs_std = np.asarray(o["std"] if o else np.ones(od), np.float32)
        self.act_mean = np.asarray(a["mean"] if a else np.zeros(ad), np.float32)
        self.act_std = np.asarray(a["std"] if a else np.ones(ad), np.float32)
        clip = spec.get("clip_actions", True)
        self.low = None if action_low is None or not clip else np.asarray(action_low, np.float32)
        self.high = None if action_high is None or not clip else np.asarray(action_high, np.float32)

    def reset(self, seed: int | None = None) -> None:
        """Nothing to reset: the policy is deterministic and stateless."""

    def act(self, obs: Obs) -> np.ndarray:
        """Action (A,) for one observation (its flat `state`), or a chunk (T, A) with the spec's `chunk`."""
        return self.act_batch([obs])[0]

    def act_batch(self, batch: list[Obs]) -> list[np.ndarray]:
        """`act` for several observations in one forward pass (`bench run vector=N`, `bench serve batch=N`), each
        answer bit for bit what `act` gives it alone (`rowwise`), so batched runs record what unbatched ones do."""
        import torch

        x = (np.stack([np.asarray(o[STATE], np.float32) for o in batch]) - self.obs_mean) / self.obs_std
        with torch.inference_mode():
            y = rowwise(self.model, torch.from_numpy(x)).numpy()
        y = y.reshape(len(batch), self.chunk, -1)
        actions = y * self.act_std + self.act_mean
        if self.low is not None:
            actions = np.clip(actions, self.low, self.high)
        actions = actions.astype(np.float32)
        if self.chunk == 1:
            return [a[0] for a in actions]
        n = self.replan_every
        return [a[:n] if n else a for a in actions]


def load_policy(path: str | Path, env=None, replan_every: int = 0) -> CheckpointPolicy:
    """Load the checkpoint at `path`; with `env`, check its obs/action names and clip to its bounds.

    Raises:
        ConfigError: missing file, unsupported type, or names that differ from the env's.
        SpecError: malformed spec or weights that do not fit the architecture.
    """
    from baselines.architectures import build

    tensors, meta = read_weights(path)
    spec = load_spec(path, meta)
    model = build(spec["architecture"], spec["obs_dim"], spec["action_dim"] * spec.get("chunk", 1), spec["kwargs"])
    _load_state(model, {k: v.float() for k, v in tensors.items()}, f"checkpoint={str(path)!r}")
    if env is None:
        policy = CheckpointPolicy(model, spec, replan_every=replan_every)
    else:
        check_names(spec, env, str(path))
        policy = CheckpointPolicy(model, spec, env.action_spec.low, env.action_spec.high, replan_every)
    # policies with equal keys answer identically, so `bench serve batch=N` answers them in one forward pass
    bounds = b"" if policy.low is None else policy.low.tobytes() + policy.high.tobytes()
    policy.batch_key = (sha256_file(Path(path)), replan_every, bounds)
    return policy


def check_names(spec: dict[str, Any], env, source: str) -> None:
    """ConfigError unless the env's state fields and action names equal the ones the policy was trained on."""
    check_declared(spec, env.obs_spec, env.action_spec.names, source)


def check_declared(spec: dict[str, Any], obs_spec: Any, action_names: Any, source: str) -> None:
    """`check_names` against an observation spec and action names (an env's, or a suite's declared ones)."""
    env_obs = [[str(n), int(w)] for n, w in obs_spec[STATE].fields]
    if env_obs != spec["obs_names"]:
        first = next(
            (i for i, (a, b) in enumerate(zip(env_obs, spec["obs_names"])) if a != b),
            min(len(env_obs), len(spec["obs_names"])),
        )
        have = env_obs[first] if first < len(env_obs) else "(end)"
        want = spec["obs_names"][first] if first < len(spec["obs_names"]) else "(end)"
        raise ConfigError(
            f"checkpoint={source!r}: obs_names differ from the env's at field {first}: policy "
            f"expects {want}, env gives {have}; the policy was trained on another observation layout"
        )
    if list(action_names) != spec["action_names"]:
        raise ConfigError(
            f"checkpoint={source!r}: action_names {spec['action_names']} differ from the env's {list(action_names)}"
        )


@dataclass(frozen=True)
class CheckpointOptions:
    """Keys of policy=checkpoint."""

    checkpoint: str  # the weights (.safetensors, or a weights-only .pt) with NAME.json, the spec, beside them
    replan_every: int = 0  # with a chunked spec: rows of each chunk executed before asking again; 0 = all


class CheckpointPlugin(PolicyPlugin):
    """`policy=checkpoint checkpoint=PATH` (entry point `bench.policies: checkpoint`)."""

    Options = CheckpointOptions

    def identity(self, options: Any) -> PolicyIdentity:
        path = Path(options.checkpoint)
        if not path.is_file():
            raise ConfigError(f"checkpoint={options.checkpoint!r}: no such file")
        return PolicyIdentity(str(options.checkpoint), sha256_file(path))

    def preflight(self, options: Any, suite: Any, cells: Sequence[Any], horizon: int) -> None:
        """Load the weights and compare the names with the first cell's, before any worker starts.

        A mismatch must stop the run with exit 2, not fill it with error records. The names come from
        the suite's declaration (`obs_spec`, `action_names`); the first cell's env is built only when
        the suite does not declare its action names (building a robosuite env costs seconds).
        """
        import torch

        replan = getattr(options, "replan_every", 0)  # PackagedBC's options have no chunking
        if replan < 0:
            raise ConfigError(f"replan_every={replan}: must be >= 0 (0 = the whole chunk)")
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            policy = load_policy(options.checkpoint)
            names = suite.action_names(cells[0]) if cells else None
            if names is not None:
                check_declared(policy.spec, suite.obs_spec(cells[0]), names, str(options.checkpoint))
            elif cells:
                env = suite.make_env(cells[0], horizon)
                try:
                    check_names(policy.spec, env, str(options.checkpoint))
                finally:
                    env.close()
        finally:
            torch.set_num_threads(threads)

    def preload(self) -> None:
        import torch  # noqa: F401  # torch: a worker started while the parent plans imports it meanwhile

    def make(self, cell: Any, env: Any, ctx: PolicyContext) -> CheckpointPolicy:
        import torch

        torch.set_num_threads(1)  # one core per worker: the runner parallelises across processes
        replan = getattr(ctx.options, "replan_every", 0)  # PackagedBC's options have no chunking
        if replan < 0:
            raise ConfigError(f"replan_every={replan}: must be >= 0 (0 = the whole chunk)")
        return load_policy(ctx.options.checkpoint, env, replan)


# the behaviour-cloning checkpoint committed with results/coverage (Lift, trained on the seen arms only)
PACKAGED_BC = Path(__file__).resolve().parent / "checkpoints" / "bc_lift_seen40.safetensors"


@dataclass(frozen=True)
class BCOptions:
    """Keys of policy=bc."""

    checkpoint: str = str(PACKAGED_BC)  # default: the packaged Lift BC checkpoint (results/coverage/README.md)


class PackagedBC(CheckpointPlugin):
    """`policy=bc`: the behaviour-cloning MLP trained on held_out_robots' seen arms (results/coverage)."""

    Options = BCOptions
