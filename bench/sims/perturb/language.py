"""The `instruction` axis: the task instruction a policy reads (`obs["task"]`) replaced by a variant of it.

Levels are words, one condition each (`perturb.instruction=[paraphrase,empty,nonsense]`):
    paraphrase   one of the suite's shipped paraphrases of the task's instruction
    synonym      every word or phrase of the instruction that the suite's synonym table lists, swapped for a synonym
    reorder      the clauses reordered: a shipped reordering when the task has one, else by rule (two clauses
                 swapped, "B, but first A"; else the final prepositional phrase fronted, "into the socket, insert
                 the peg"; else the object fronted, "the drawer, open it")
    distractor   an irrelevant clause from the suite's list appended ("..., while the radio plays softly")
    empty        the control with no words: ""
    nonsense     the control with no meaning: as many words as the instruction, drawn from `NONSENSE`
Every choice draws from the episode's generator (`condition_rng`), so a seed gives the same text in any worker.

Data: a suite ships its paraphrase sets as JSON (`Suite.instructions`: a package-data file) —
`{"synonyms": {phrase: [alternatives]}, "distractors": [clauses], "tasks": {task: {"instruction": text,
"paraphrase": [texts], "reorder": [texts] (optional)}}}`. `prepare` (called by the run's plan, before anything is
written) refuses a run that would measure nothing — a suite or cell without an instruction, a policy that reads
none, a variant the data cannot make — and puts the run's tasks' data in each condition's spec, from which the
rollout binds the episode's `InstructionView`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from bench.core.errors import ConfigError, DataError
from bench.protocols import TASK, Cell, EnvAdapter, Obs, Suite
from bench.protocols.env import AdapterWrapper
from bench.protocols.suite import Condition
from bench.sims.perturb.axis import Axis, Params

NAME = "instruction"
VARIANTS = ("paraphrase", "synonym", "reorder", "distractor", "empty", "nonsense")
CONTROLS = ("empty", "nonsense")  # variants that carry no instruction at all
# words with no bearing on any table-top task (none is a task's object, place or verb)
NONSENSE = (
    "violet",
    "seventeen",
    "whisper",
    "marmalade",
    "thunder",
    "cloudy",
    "quietly",
    "pencil",
    "orbit",
    "lantern",
    "velvet",
    "gravel",
    "melody",
    "harbour",
    "yesterday",
    "saxophone",
    "meadow",
    "tangerine",
    "cathedral",
    "bicycle",
)
# words that open a phrase `reorder` may front ("into the socket, insert the peg")
PREPOSITIONS = frozenset("into onto inside towards toward through across under behind off from with at to on".split())
DETERMINERS = ("the", "a", "an")
_SPLIT = re.compile(r",? and then |, then |,? and ")  # two clauses: "A and B", "A, then B"
InstructionData = dict[str, Any]  # what a condition's spec carries: the data file's entries for the run's tasks


def varies(condition: Condition) -> bool:
    """Whether `condition` varies the instruction (its episodes get a shadow policy and an `InstructionView`)."""
    return condition.axis == NAME


# -- variants ------------------------------------------------------------------------------------------------
def _strip(text: str) -> tuple[str, str]:
    """(the instruction without its final full stop, the stop: "." or "")."""
    text = text.strip()
    return (text[:-1], ".") if text.endswith(".") else (text, "")


def _cased(text: str, like: str) -> str:
    """`text` with its first letter in the case of `like`'s."""
    if not text or not like:
        return text
    return (text[0].upper() if like[0].isupper() else text[0].lower()) + text[1:]


def synonym(text: str, table: Mapping[str, Sequence[str]], rng: np.random.Generator) -> str:
    """Every phrase of `table` found in `text` (whole words; the longest where they overlap) swapped for one of its
    synonyms, in one pass (a synonym is never swapped again)."""
    if not table:
        return text
    lower = {k.lower(): v for k, v in table.items()}
    alternatives = "|".join(re.escape(k) for k in sorted(lower, key=len, reverse=True))
    pattern = re.compile(rf"\b(?:{alternatives})\b", re.IGNORECASE)

    def swap(m: re.Match[str]) -> str:
        options = lower[m.group(0).lower()]
        return _cased(str(options[int(rng.integers(len(options)))]), m.group(0))

    return pattern.sub(swap, text)


def reorder(text: str) -> str:
    """The clauses of `text` reordered by rule (see the module doc); `text` itself when no rule applies."""
    body, stop = _strip(text)
    parts = _SPLIT.split(body, maxsplit=1)
    if len(parts) == 2 and all(len(p.split()) >= 3 for p in parts):  # clauses, not "the red and white target"
        first, second = (p.strip() for p in parts)
        return _cased(f"{second}, but first {_cased(first, 'a')}{stop}", body)
    words = body.split()
    for i in range(len(words) - 1, 0, -1):  # the last prepositional phrase, fronted
        if words[i].lower() in PREPOSITIONS and i + 1 < len(words):
            return _cased(f"{' '.join(words[i:])}, {_cased(' '.join(words[:i]), 'a')}{stop}", body)
    for i, w in enumerate(words[1:], start=1):  # the object, fronted: "the drawer, open it"
        if w.lower() in DETERMINERS:
            return _cased(f"{' '.join(words[i:])}, {_cased(' '.join(words[:i]), 'a')} it{stop}", body)
    return text


def nonsense(text: str, rng: np.random.Generator) -> str:
    """As many words as `text` (at least 3) drawn from `NONSENSE`, none of them a word of `text`."""
    own = set(re.findall(r"[a-z]+", text.lower()))
    pool = [w for w in NONSENSE if w not in own]
    n = max(3, len(text.split()))
    return " ".join(pool[int(k)] for k in rng.integers(len(pool), size=n))


def variant_text(variant: str, task: str, data: InstructionData, rng: np.random.Generator) -> str:
    """The text of `variant` of `task`'s instruction, drawn with `rng` from the shipped `data`."""
    entry = data["tasks"][task]
    true = str(entry["instruction"])
    if variant == "paraphrase":
        return str(entry["paraphrase"][int(rng.integers(len(entry["paraphrase"])))])
    if variant == "synonym":
        return synonym(true, data.get("synonyms") or {}, rng)
    if variant == "reorder":
        shipped = entry.get("reorder") or []
        return str(shipped[int(rng.integers(len(shipped)))]) if shipped else reorder(true)
    if variant == "distractor":
        body, stop = _strip(true)
        clauses = data["distractors"]
        return f"{body}, {clauses[int(rng.integers(len(clauses)))]}{stop}"
    if variant == "empty":
        return ""
    if variant == "nonsense":
        return nonsense(true, rng)
    raise ValueError(f"unknown instruction variant {variant!r}; valid: {', '.join(VARIANTS)}")


# -- the episode's view of the env ----------------------------------------------------------------------------
class InstructionView(AdapterWrapper):
    """The env seen with the instruction replaced by a variant of it: chosen at reset (from the data the rollout
    binds, with the episode's generator) and put in every observation's `task` entry.

    `true` and `text` hold the env's own instruction and the one the policy saw, once reset."""

    def __init__(self, env: EnvAdapter, rng: np.random.Generator, variant: str):
        super().__init__(env)
        self.rng, self.variant = rng, str(variant)
        self.data: InstructionData | None = None
        self.task = ""
        self.true: str | None = None
        self.text: str | None = None

    def bind(self, data: InstructionData | None, task: str) -> None:
        """The paraphrase data of the run (`prepare` put it in the condition's spec) and the episode's task."""
        self.data, self.task = data, task

    def _seen(self, obs: Obs) -> Obs:
        return {**obs, TASK: self.text}

    def reset(self, seed: int) -> Obs:
        obs = self.inner.reset(seed)
        if self.data is None or self.task not in self.data.get("tasks", {}):
            raise RuntimeError(f"perturb.{NAME}: no paraphrase data bound for task {self.task!r}")
        self.true = str(obs.get(TASK, ""))
        shipped = self.data["tasks"][self.task]["instruction"]
        if self.true != shipped:
            raise RuntimeError(
                f"perturb.{NAME}: the env's instruction {self.true!r} is not the one the paraphrase data of "
                f"{self.task} varies ({shipped!r})"
            )
        self.text = variant_text(self.variant, self.task, self.data, self.rng)
        return self._seen(obs)

    def step(self, action: Any) -> tuple[Obs, float, bool, bool, dict[str, object]]:
        obs, reward, terminated, truncated, info = self.inner.step(action)
        return self._seen(obs), reward, terminated, truncated, info


def view_of(env: EnvAdapter) -> InstructionView | None:
    """The `InstructionView` among `env` and the adapters it wraps, or None."""
    while isinstance(env, AdapterWrapper):
        if isinstance(env, InstructionView):
            return env
        env = env.inner
    return None


def _wrap(env: EnvAdapter, rng: np.random.Generator, level: str) -> tuple[EnvAdapter, Params]:
    return InstructionView(env, rng, level), {}


ROWS: tuple[Axis, ...] = (
    Axis(
        NAME,
        "language",
        "a variant: " + ", ".join(VARIANTS),
        "the task instruction replaced by a variant",
        "the instruction in obs['task'] replaced by a paraphrase, synonyms, reordered clauses, an added distractor "
        "clause, or the controls: empty and nonsense",
        words=VARIANTS,
        nominal=0.0,
        wrap=_wrap,
    ),
)


# -- before the run: refusals and the data each condition carries ---------------------------------------------
def load(path: str | Path) -> dict[str, Any]:
    """A suite's paraphrase data file, checked for shape (DataError naming the file and the field)."""
    path = Path(path)
    try:
        raw = path.read_bytes()
        doc = json.loads(raw)
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise DataError(f"{path}: cannot read the paraphrase data ({exc})") from None
    tasks = doc.get("tasks") if isinstance(doc, dict) else None
    if not isinstance(tasks, dict) or not tasks:
        raise DataError(f"{path}: field 'tasks' must map task names to their instruction and paraphrases")
    for task, entry in tasks.items():
        if not isinstance(entry, dict) or not isinstance(entry.get("instruction"), str):
            raise DataError(f"{path}: tasks.{task}.instruction must be a string")
        for key in ("paraphrase", "reorder"):
            texts = entry.get(key, [] if key == "reorder" else None)
            if not isinstance(texts, list) or not all(isinstance(t, str) and t.strip() for t in texts):
                raise DataError(f"{path}: tasks.{task}.{key} must be a list of non-empty strings")
    syn = doc.get("synonyms", {})
    if not isinstance(syn, dict) or not all(isinstance(v, list) and v for v in syn.values()):
        raise DataError(f"{path}: field 'synonyms' must map phrases to non-empty lists of synonyms")
    dis = doc.get("distractors")
    if not isinstance(dis, list) or not dis or not all(isinstance(t, str) and t.strip() for t in dis):
        raise DataError(f"{path}: field 'distractors' must be a non-empty list of clauses")
    return {**doc, "source": str(path), "sha256": hashlib.sha256(raw).hexdigest()}


def _refuse_empty_variant(variant: str, task: str, data: InstructionData) -> None:
    """A variant the data cannot make differ from the true instruction is refused (it would measure nothing)."""
    entry = data["tasks"][task]
    true = entry["instruction"]
    if variant == "paraphrase" and not entry["paraphrase"]:
        why = "has no paraphrase"
    elif variant == "synonym" and synonym(true, data.get("synonyms") or {}, np.random.default_rng(0)) == true:
        why = "has no word the synonym table lists"
    elif variant == "reorder" and not entry.get("reorder") and reorder(true) == true:
        why = "has one clause and no phrase to front, and no shipped reordering"
    else:
        return
    raise ConfigError(
        f"perturb.{NAME}={variant}: the instruction of {task} ({true!r}) {why} in {data['source']}; "
        "add one there or leave the variant out"
    )


def prepare(
    conditions: Sequence[Condition], suite: Suite, cells: Sequence[Cell], needs: Sequence[str], policy: str
) -> list[Condition]:
    """Refuse an instruction axis that would measure nothing, and give its conditions the run's paraphrase data.

    Refused (ConfigError, one line, before anything is written): a cell whose observation has no instruction
    (`task`), a suite that ships no paraphrase data or none for a cell's task, a variant the data cannot make,
    and a policy that reads no instruction (`needs`: its declared observation keys; none = the whole observation,
    as for `check_policy_sees`) — its actions could not depend on the words. Returns `conditions` with each
    instruction condition's spec carrying `instructions`: the data of the run's tasks.
    """
    wanted = [c for c in conditions if varies(c)]
    if not wanted:
        return list(conditions)
    for cell in cells:
        spec = suite.obs_spec(cell)
        if TASK not in spec:
            raise ConfigError(
                f"perturb.{NAME}: suite {suite.name!r} cell {cell.key} gives the policy no instruction (it observes "
                f"{', '.join(spec)}); the axis needs a suite whose tasks carry one (aloha, pusht, held_out_envs, "
                "maniskill_tasks) or leave it out"
            )
        reads = tuple(needs) or tuple(spec)
        if TASK not in reads:
            raise ConfigError(
                f"perturb.{NAME} changes only the instruction (obs[{TASK!r}]), and policy {policy!r} reads none (it "
                f"reads {', '.join(reads)}): the action difference would be 0 by construction; use a policy that "
                f"reads {TASK!r} (e.g. metaworld_language, or remote with a {TASK} entry in obs_map) or leave the "
                "axis out"
            )
    source = suite.instructions
    if not source:
        raise ConfigError(f"perturb.{NAME}: suite {suite.name!r} ships no paraphrase data (Suite.instructions)")
    data = load(source)
    tasks = sorted({c.task for c in cells})
    missing = [t for t in tasks if t not in data["tasks"]]
    if missing:
        raise ConfigError(f"perturb.{NAME}: {source} has no paraphrases of task(s) {', '.join(missing)}")
    run_data: InstructionData = {
        "source": data["source"],
        "sha256": data["sha256"],
        "synonyms": data.get("synonyms") or {},
        "distractors": data["distractors"],
        "tasks": {t: data["tasks"][t] for t in tasks},
    }
    for cond in wanted:
        for task in tasks:
            _refuse_empty_variant(str(cond.level), task, run_data)
    return [dataclasses.replace(c, spec={**c.spec, "instructions": run_data}) if varies(c) else c for c in conditions]
