"""`obs_map=`: which observation entries a policy server gets, under which names.

An entry is `WIRE_KEY:SOURCE`; the map is a list of them, e.g. for openpi's LIBERO policies

    obs_map=[observation/image:rgb.agentview,observation/wrist_image:rgb.eye_in_hand,observation/state:state,prompt:task]

SOURCE is one of
    state, rgb.<camera>, depth.<camera>    an entry of the env's observation (its declared spec);
    state.<field>[+state.<field>...]       named fields of the state vector, concatenated (float32);
    task                                   the task instruction: the env's `task` entry when it has
                                           one, else the cell's task name (e.g. "Lift").

Only the listed entries are sent (select + rename). Without `obs_map` the whole observation
goes under bench's own names (`state`, `rgb.<camera>`, ...), plus `task` — what `bench serve`
expects. A server (`bench serve obs_map=...`) reads the same syntax the other way round:
wire key -> bench key (plain keys only; a field selection cannot be inverted).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from bench.core.errors import ConfigError, did_you_mean
from bench.protocols import DEPTH, RGB, STATE, TASK, Feature, Obs, ObsSpec
from bench.remote.wire import Message

FIELD_PREFIX = STATE + "."


@dataclass(frozen=True)
class Entry:
    """One `WIRE_KEY:SOURCE` entry, parsed."""

    wire: str
    source: str  # as written
    keys: tuple[str, ...]  # the observation entries it reads ("state" for field selections)
    fields: tuple[str, ...] = ()  # state fields, when SOURCE selects some


def parse(entries: Sequence[str] | None, key: str = "obs_map") -> list[Entry] | None:
    """Parse `obs_map` entries (ConfigError naming the bad one); None stays None (send everything)."""
    if entries is None:
        return None
    if isinstance(entries, str):
        entries = [entries]
    out: list[Entry] = []
    for item in entries:
        text = str(item)
        wire, sep, source = text.rpartition(":")
        wire, source = wire.strip(), source.strip()
        if not sep or not wire or not source:
            raise ConfigError(
                f"{key}: entry {text!r} is not WIRE_KEY:SOURCE (e.g. observation/state:state, prompt:task)"
            )
        if wire == "__bench__":
            raise ConfigError(f"{key}: wire key {wire!r} is reserved for the protocol's control messages")
        if source.startswith(FIELD_PREFIX):
            fields = tuple(f[len(FIELD_PREFIX) :] if f.startswith(FIELD_PREFIX) else "" for f in source.split("+"))
            if not all(fields):
                raise ConfigError(f"{key}: entry {text!r}: a field selection is state.<field>[+state.<field>...]")
            out.append(Entry(wire, source, (STATE,), fields))
        elif source in (STATE, TASK) or source.startswith((RGB, DEPTH)):
            out.append(Entry(wire, source, (source,)))
        else:
            raise ConfigError(
                f"{key}: entry {text!r}: source {source!r} is not state, state.<field>, "
                "rgb.<camera>, depth.<camera> or task"
            )
    wires = [e.wire for e in out]
    twice = next((w for i, w in enumerate(wires) if w in wires[:i]), None)
    if twice is not None:
        raise ConfigError(f"{key}: wire key {twice!r} is given twice")
    return out


def env_keys(entries: list[Entry] | None) -> tuple[str, ...]:
    """The observation entries the map reads from the env (`task` is always available; not listed).

    Without a map the whole observation is sent, whatever it holds: nothing is required.
    """
    if entries is None:
        return ()
    keys: list[str] = []
    for e in entries:
        keys += [k for k in e.keys if k != TASK and k not in keys]
    return tuple(keys)


def check(entries: list[Entry] | None, spec: ObsSpec, where: str, key: str = "obs_map") -> None:
    """ConfigError unless every source exists in the observation `spec` (named fields included)."""
    for e in entries or []:
        for k in e.keys:
            if k != TASK and k not in spec:
                raise ConfigError(
                    f"{key}: {e.wire}:{e.source} reads {k!r}, which {where} does not provide; it "
                    f"provides {', '.join(spec)}.{did_you_mean(k, list(spec))}"
                )
        if e.fields:
            names = [n for n, _ in spec[STATE].fields]
            for f in e.fields:
                if f not in names:
                    raise ConfigError(
                        f"{key}: {e.wire}:{e.source}: the state of {where} has no field {f!r}; "
                        f"fields: {', '.join(names)}.{did_you_mean(f, names)}"
                    )


def wire_spec(entries: list[Entry] | None, spec: ObsSpec) -> dict[str, dict[str, object]]:
    """What the client sends under each wire key: {"shape": [...], "dtype": ...} ("str" for the task).

    Sent with the preflight "check", so a server can name an input it will not get, or one of the wrong
    shape, before any episode (the lerobot adapter compares it with its policy's input features).
    """
    if entries is None:
        out: dict[str, dict[str, object]] = {k: {"shape": list(f.shape), "dtype": f.dtype} for k, f in spec.items()}
        out.setdefault(TASK, {"shape": [], "dtype": "str"})
        return out
    sent: dict[str, dict[str, object]] = {}
    for e in entries:
        if e.fields:
            widths = dict(spec[STATE].fields)
            sent[e.wire] = {"shape": [sum(widths[f] for f in e.fields)], "dtype": "float32"}
        elif e.keys == (TASK,):
            sent[e.wire] = {"shape": [], "dtype": "str"}
        else:
            feature = spec[e.keys[0]]
            sent[e.wire] = {"shape": list(feature.shape), "dtype": feature.dtype}
    return sent


class ClientMap:
    """Builds the message a server gets from one observation (select, rename, slice state fields)."""

    def __init__(self, entries: list[Entry] | None, spec: ObsSpec, task: str):
        self.entries, self.task = entries, task
        state = spec.get(STATE)
        offsets: dict[str, slice] = {}
        start = 0
        for name, width in state.fields if isinstance(state, Feature) else ():
            offsets[name] = slice(start, start + width)
            start += width
        self._slices = {e.wire: [offsets[f] for f in e.fields] for e in entries or [] if e.fields}

    def __call__(self, obs: Obs) -> Message:
        if self.entries is None:
            out = dict(obs)
            out.setdefault(TASK, self.task)
            return out
        msg: Message = {}
        for e in self.entries:
            if e.fields:
                state = obs[STATE]
                parts = [state[s] for s in self._slices[e.wire]]
                msg[e.wire] = np.concatenate(parts).astype(np.float32, copy=False) if len(parts) > 1 else parts[0]
            elif e.source == TASK:
                msg[e.wire] = obs.get(TASK, self.task)
            else:
                msg[e.wire] = obs[e.source]
        return msg


def server_map(entries: list[Entry] | None, key: str = "obs_map") -> dict[str, str] | None:
    """wire key -> bench key for a server (ConfigError for field selections, which cannot be inverted)."""
    if entries is None:
        return None
    for e in entries:
        if e.fields:
            raise ConfigError(
                f"{key}: {e.wire}:{e.source}: a server can only rename whole entries "
                "(state, rgb.<camera>, depth.<camera>, task), not select state fields"
            )
    return {e.wire: e.source for e in entries}
