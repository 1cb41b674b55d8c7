"""The corpus of hand-written hostile inputs (see tests/hostile.py for how each is checked).

Each case names its family (the issue's: data loss, traceback, silent acceptance, unbounded work,
left behind, unreadable output), the command line (`{ws}`: the workspace of valid inputs, `{case}`:
the case's own folder, where its setup wrote the bad files) and a regex the one stderr line must
match — the field it names.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

from hostile import FAMILIES, SPEC_YAML, TOY, Case, copy, edit_json, write

DL, TB, SA, UW, LB, UO = FAMILIES[:6]  # the six families
CASES: list[Case] = []


def add(family: str, name: str, argv: list[str], match: str, **kw) -> None:
    CASES.append(Case(family, name, argv, match, **kw))


def _parent(doc, path: str):
    """(the container holding the item at `path`, its key): a dotted (or /-separated) path; integers index lists."""
    keys = [int(k) if k.lstrip("-").isdigit() else k for k in path.split("/" if "/" in path else ".")]
    node = doc
    for k in keys[:-1]:
        node = node[k]
    return node, keys[-1]


def _set(path: str, value):
    """fn(doc) setting doc[a][b]... (a dotted path; integers index lists) to `value`."""

    def fn(doc):
        node, key = _parent(doc, path)
        node[key] = value

    return fn


def _del(path: str):
    def fn(doc):
        node, key = _parent(doc, path)
        del node[key]

    return fn


def _truncate(rel: str, keep: float = 0.5):
    def edit(root: Path) -> None:
        p = root / rel if rel else root
        data = p.read_bytes()
        p.write_bytes(data[: int(len(data) * keep)])

    return edit


def _bytes(rel: str, data: bytes):
    def edit(root: Path) -> None:
        (root / rel if rel else root).write_bytes(data)

    return edit


RUN = ["run", TOY, "workers=1", "episodes=1", "out={case}/runs"]

# ----------------------------------------------------------------------------- data loss
add(
    DL,
    "report-into-its-run-dir",
    ["report", "{case}/run", "out={case}/run"],
    r"out=.*(is|contains|inside).*input",
    setup=copy("run", "run"),
)
add(
    DL,
    "report-into-its-run-dir-overwrite",
    ["report", "{case}/run", "out={case}/run", "overwrite=true"],
    r"out=.*input",
    setup=copy("run", "run"),
)
add(
    DL,
    "report-inside-its-run-dir",
    ["report", "{case}/run", "out={case}/run/report"],
    r"out=.*inside.*input",
    setup=copy("run", "run"),
)
add(
    DL,
    "report-out-parent-of-cwd",
    ["report", "run", "out=.."],
    r"out=.*contains.*input",
    setup=copy("run", "work/run"),
    cwd="{case}/work",
)
add(
    DL,
    "report-out-cwd-parent-overwrite",
    ["report", "run", "out=..", "overwrite=true"],
    r"out=.*input",
    setup=copy("run", "work/run"),
    cwd="{case}/work",
)
add(
    DL,
    "report-out-cwd",
    ["report", "run", "out=.", "overwrite=true"],
    r"out=.*input",
    setup=copy("run", "work/run"),
    cwd="{case}/work",
)
add(
    DL,
    "report-over-foreign-folder",
    ["report", "{ws}/run", "out={case}/mine", "overwrite=true"],
    r"out=.*(not written by bench|bench did not write)",
    setup=write("mine/notes.txt", "my notes"),
)
add(
    DL,
    "report-over-foreign-folder-no-overwrite",
    ["report", "{ws}/run", "out={case}/mine"],
    r"out=.*(exists|not empty).*overwrite",
    setup=write("mine/notes.txt", "my notes"),
)
add(
    DL,
    "report-over-a-file",
    ["report", "{ws}/run", "out={case}/file.txt"],
    r"out=.*(file|folder)",
    setup=write("file.txt", "x"),
)
add(
    DL,
    "import-out-cwd-overwrite",
    ["logs", "import", "data.csv", "out=.", "overwrite=true", "time=t"],
    r"out=.*(contains|is).*input",
    setup=copy("data.csv", "data.csv"),
)
add(
    DL,
    "import-out-parent-overwrite",
    ["logs", "import", "data.csv", "out=..", "overwrite=true", "time=t"],
    r"out=.*contains.*input",
    setup=copy("data.csv", "sub/data.csv"),
    cwd="{case}/sub",
)
add(
    DL,
    "import-out-parent-no-overwrite",
    ["logs", "import", "data.csv", "out=..", "time=t"],
    r"out=.*contains.*input",
    setup=copy("data.csv", "sub/data.csv"),
    cwd="{case}/sub",
)
add(
    DL,
    "import-over-foreign-folder",
    ["logs", "import", "{ws}/data.csv", "out={case}/d", "overwrite=true", "time=t"],
    r"out=.*(not written by bench|bench did not write)",
    setup=write("d/precious.txt", "keep me"),
)
add(
    DL,
    "import-over-the-source-folder",
    ["logs", "import", "{case}/ds2/data.csv", "out={case}/ds2", "overwrite=true", "time=t"],
    r"out=.*input",
    setup=copy("data.csv", "ds2/data.csv"),
)
add(
    DL,
    "leaderboard-merge-over-its-input",
    ["leaderboard", "merge", "{case}/lb.json", "{ws}/run", "out={case}/lb.json"],
    r"out=.*input",
    setup=copy("lb.json", "lb.json"),
)
add(
    DL,
    "leaderboard-merge-over-its-summary",
    ["leaderboard", "merge", "{case}/run/summary.json", "out={case}/run/summary.json"],
    r"out=.*input",
    setup=copy("run", "run"),
)
add(
    DL,
    "leaderboard-merge-into-run-dir",
    ["leaderboard", "merge", "{case}/run", "out={case}/run/lb.json"],
    r"out=.*inside.*input",
    setup=copy("run", "run"),
)
add(
    DL,
    "leaderboard-merge-over-other-file",
    ["leaderboard", "merge", "{ws}/run", "out={case}/notes.json"],
    r"out=.*exists.*overwrite",
    setup=write("notes.json", '{"mine": 1}'),
)
add(
    DL,
    "leaderboard-merge-overwrite-foreign-file",
    ["leaderboard", "merge", "{ws}/run", "out={case}/notes.json", "overwrite=true"],
    r"out=.*(not written by bench|bench)",
    setup=write("notes.json", '{"mine": 1}'),
)
add(
    DL,
    "correlate-over-its-input",
    ["correlate", "sim={case}/sim.json", "real={ws}/real.json", "out={case}/sim.json"],
    r"out=.*input",
    setup=copy("sim.json", "sim.json"),
)
add(
    DL,
    "correlate-over-real",
    ["correlate", "sim={ws}/sim.json", "real={case}/real.json", "out={case}/real.json", "overwrite=true"],
    r"out=.*input",
    setup=copy("real.json", "real.json"),
)
add(
    DL,
    "correlate-over-existing",
    ["correlate", "sim={ws}/sim.json", "real={ws}/real.json", "out={case}/x.json"],
    r"out=.*exists.*overwrite",
    setup=write("x.json", "{}"),
)
add(
    DL,
    "replay-into-logs",
    ["replay", "logs={case}/ds", "spec={ws}/spec.yaml", "out={case}/ds"],
    r"out=.*input",
    setup=copy("ds", "ds"),
)
add(
    DL,
    "replay-inside-logs",
    ["replay", "logs={case}/ds", "spec={ws}/spec.yaml", "out={case}/ds/replay"],
    r"out=.*inside.*input",
    setup=copy("ds", "ds"),
)
add(
    DL,
    "calibrate-into-logs",
    ["calibrate", "spec={ws}/spec.yaml", "logs={case}/ds", "out={case}/ds", "residual=false", "quiet=true"],
    r"out=.*input",
    setup=copy("ds", "ds"),
)
add(
    DL,
    "calibrate-over-spec-folder",
    ["calibrate", "spec={case}/m/spec.yaml", "logs={ws}/ds", "out={case}/m", "residual=false", "quiet=true"],
    r"out=.*input",
    setup=lambda ws, c: (copy("spec.yaml", "m/spec.yaml")(ws, c), copy("arm.xml", "m/arm.xml")(ws, c)),
)
add(
    DL,
    "card-out-inside-dataset",
    ["logs", "card", "{case}/ds", "out={case}/ds/card.json"],
    r"out=.*inside.*input",
    setup=copy("ds", "ds"),
)
add(
    DL,
    "card-out-over-info",
    ["logs", "card", "{case}/ds", "out={case}/ds/meta/info.json"],
    r"out=.*",
    setup=copy("ds", "ds"),
)
add(DL, "run-record-is-run-dir", [*RUN, "run_id=r", "record={case}/runs/r"], r"record=.*(inside|contains|run)")
add(
    DL,
    "run-record-existing-dataset",
    [*RUN, "run_id=r", "record={case}/ds"],
    r"record=.*(exists|not empty)",
    setup=copy("ds", "ds"),
)
add(
    DL,
    "run-out-is-a-file",
    ["run", TOY, "workers=1", "episodes=1", "out={case}/f", "run_id=r"],
    r"out=.*(file|folder)",
    setup=write("f", "x"),
)
add(
    DL,
    "run-resume-foreign-folder",
    [*RUN, "run_id=mine"],
    r"run_id=.*(not a run|bench did not write|run.json)",
    setup=write("runs/mine/notes.txt", "mine"),
)
add(
    DL,
    "run-resume-other-config",
    ["run", TOY, "workers=1", "episodes=2", "run_id=run", "out={case}", "seed=3", "n_boot=200"],
    r"seed",
    setup=copy("run", "run"),
)
add(
    DL,
    "coverage-out-over-data",
    ["coverage", "data={case}/ds", "suite=tests.toy_suite:ToySuite", "episodes=1", "out={case}/ds/meta/info.json"],
    r"out=.*",
    setup=copy("ds", "ds"),
)
add(
    DL,
    "actions-out-over-logs",
    ["actions", "logs={case}/ds", "suite=tests.toy_suite:ToySuite", "out={case}/ds/meta/stats.json"],
    r"out=.*",
    setup=copy("ds", "ds"),
)
add(
    DL,
    "bc-out-over-data",
    ["data=[{case}/ds]", "out={case}/ds/policy.safetensors", "epochs=1"],
    r"out=.*",
    setup=copy("ds", "ds"),
    main="baselines.bc",
)
add(
    DL,
    "bc-out-existing-foreign",
    ["data=[{ws}/ds]", "out={case}/w.safetensors", "epochs=1"],
    r"out=.*(exists|overwrite)",
    setup=write("w.safetensors", b"not mine"),
    main="baselines.bc",
)
add(
    DL,
    "calibrate-generate-over-foreign",
    ["calibrate", "generate", "effect=none", "out={case}/g", "episodes=2", "duration=1"],
    r"out=.*(exists|not empty|overwrite)",
    setup=write("g/keep.txt", "keep"),
)

# ----------------------------------------------------------------------------- config grammar / run keys
for name, extra, match in [
    ("horizon-million", ["horizon=1000000"], r"horizon=1000000: must be in"),
    ("horizon-negative", ["horizon=-1"], r"horizon=-1"),
    ("workers-100k", ["workers=100000"], r"workers=100000"),
    ("episodes-huge", ["episodes=10000000000"], r"episodes"),
    ("timeout-zero", ["timeout=0"], r"timeout"),
    ("timeout-negative", ["timeout=-5"], r"timeout"),
    ("timeout-nan", ["timeout=nan"], r"timeout"),
    ("timeout-inf", ["timeout=inf"], r"timeout"),
    ("seed-negative", ["seed=-1"], r"seed=-1"),
    ("seed-huge", ["seed=100000000000000000000000"], r"seed"),
    ("n-boot-huge", ["n_boot=1000000000000"], r"n_boot"),
    ("n-boot-zero", ["n_boot=0"], r"n_boot"),
    ("confidence-nan", ["confidence=nan"], r"confidence"),
    ("confidence-1", ["confidence=1"], r"confidence"),
    ("run-id-dotdot", ["run_id=.."], r"run_id"),
    ("run-id-slash", ["run_id=a/b"], r"run_id"),
    ("run-id-long", ["run_id=" + "a" * 300], r"run_id"),
    ("run-id-empty", ["run_id="], r"run_id"),
    ("run-id-nul", ["run_id=a\x00b"], r"run_id"),
    ("robots-empty", ["robots=[]"], r"robots"),
    ("robots-unknown", ["robots=[z]"], r"robots"),
    ("key-twice", ["seed=1", "seed=2"], r"seed.*twice"),
    ("unknown-key", ["epsiodes=3"], r"unknown key 'epsiodes'"),
    ("suite-key-nan", ["goal=nan"], r"goal"),
    ("suite-key-inf", ["goal=inf"], r"goal"),
    ("suite-key-huge-int", ["fault_step=100000000000000000000000"], r"fault_step"),
    ("suite-key-wrong-type", ["goal=abc"], r"goal"),
    ("checkpoint-without-policy", ["checkpoint=x.safetensors"], r"unknown key 'checkpoint'"),
    ("perturb-scale-1e300", ["perturb.mass=[1e300]"], r"perturb"),
    ("perturb-nan", ["perturb.latency=[nan]"], r"perturb"),
    ("perturb-negative-latency", ["perturb.latency=[-3]"], r"perturb"),
    ("perturb-huge-latency", ["perturb.latency=[100000000]"], r"perturb"),
    ("perturb-inf-noise", ["perturb.action_noise=[inf]"], r"perturb"),
    ("perturb-uniform-reversed", ["perturb.action_noise=uniform(0.5,0.1)"], r"perturb"),
    ("perturb-unknown-axis", ["perturb.frobnicate=[1]"], r"perturb"),
    ("video-negative", ["video=-1"], r"video"),
    ("metric-unknown", ["metric=speed"], r"metric"),
    ("interp-missing", ["run_id=${nope}"], r"run_id|interpolat|nope"),
    ("interp-env", ["seed=${oc.env:NO_SUCH_VAR_XYZ}"], r"seed|NO_SUCH_VAR_XYZ|interpolat"),
    ("bad-list-syntax", ["robots=[a"], r"robots"),
    ("nested-conflict", ["perturb.latency=[1]", "perturb.latency.levels=[2]"], r"perturb.latency"),
    ("equals-only", ["="], r"="),
    ("empty-key", ["=5"], r"=5"),
    ("dict-for-int", ["episodes={a: 1}"], r"episodes"),
    ("list-for-int", ["seed=[1,2]"], r"seed"),
    ("bool-for-int", ["episodes=true"], r"episodes"),
    ("float-for-int", ["episodes=2.5"], r"episodes"),
    ("calibration-missing", ["calibration={case}/nope.json"], r"calibration"),
    ("calibration-garbage", ["calibration={case}/c.json"], r"c.json"),
    ("policy-module-missing", ["policy=nosuchmod.x:make"], r"policy"),
    ("policy-attr-missing", ["policy=json:nosuch"], r"policy"),
    ("policy-not-callable", ["policy=json:__version__"], r"policy"),
]:
    add(
        SA
        if name not in ("horizon-million", "episodes-huge", "n-boot-huge", "workers-100k", "perturb-huge-latency")
        else UW,
        f"run-{name}",
        [*RUN, *extra],
        match,
        setup=write("c.json", b"\xff\xfe{garbage") if name == "calibration-garbage" else None,
    )

add(SA, "run-checkpoint-missing", [*RUN, "policy=checkpoint", "checkpoint={case}/nope.safetensors"], r"checkpoint")
add(
    TB,
    "run-checkpoint-garbage",
    [*RUN, "policy=checkpoint", "checkpoint={case}/w.safetensors"],
    r"checkpoint|w\.",
    setup=write("w.safetensors", b"\x00" * 64),
)
add(
    TB,
    "run-checkpoint-truncated",
    [*RUN, "policy=checkpoint", "checkpoint={case}/ckpt/policy.safetensors"],
    r"checkpoint|policy",
    setup=copy("ckpt", "ckpt", _truncate("policy.safetensors", 0.6)),
)
add(
    TB,
    "run-checkpoint-spec-not-utf8",
    [*RUN, "policy=checkpoint", "checkpoint={case}/ckpt/policy.safetensors"],
    r"policy\.json|spec",
    setup=copy("ckpt", "ckpt", _bytes("policy.json", b"\xff\xfe\x00garbage")),
)
add(
    TB,
    "run-checkpoint-spec-nan-norm",
    [*RUN, "policy=checkpoint", "checkpoint={case}/ckpt/policy.safetensors"],
    r"normalization|NaN|spec",
    setup=copy(
        "ckpt",
        "ckpt",
        edit_json("policy.json", _set("normalization", {"obs": {"mean": [float("nan"), 0], "std": [1, 1]}})),
    ),
)


def _nan_weights(root: Path) -> None:
    import torch
    from safetensors.torch import load_file, save_file

    from baselines.checkpoint import METADATA_KEY

    p = root / "policy.safetensors"
    state = load_file(str(p))
    key = sorted(state)[0]
    state[key] = state[key].clone()
    state[key].view(-1)[0] = float("nan")
    spec = json.loads((root / "policy.json").read_text())
    save_file(state, str(p), metadata={METADATA_KEY: json.dumps(spec, sort_keys=True, separators=(",", ":"))})
    del torch


add(
    SA,
    "run-checkpoint-nan-weights",
    [*RUN, "policy=checkpoint", "checkpoint={case}/ckpt/policy.safetensors"],
    r"NaN|non-finite|inf",
    setup=copy("ckpt", "ckpt", _nan_weights),
)
add(
    LB,
    "run-record-unwritable",
    [*RUN, "run_id=r", "record={case}/ro/rec"],
    r"record=.*(writ|permission)",
    setup=lambda ws, c: ((c / "ro").mkdir(), (c / "ro").chmod(0o500)),
)
add(
    LB,
    "run-record-under-a-file",
    [*RUN, "run_id=r", "record={case}/f/rec"],
    r"record=.*(file|folder)",
    setup=write("f", "x"),
)
add(
    LB,
    "run-out-unwritable",
    ["run", TOY, "workers=1", "episodes=1", "out={case}/ro/runs", "run_id=r"],
    r"out=.*(writ|permission)",
    setup=lambda ws, c: ((c / "ro").mkdir(), (c / "ro").chmod(0o500)),
)
add(
    LB,
    "run-long-component",
    ["run", TOY, "workers=1", "episodes=1", "out={case}/" + "d" * 300, "run_id=r"],
    r"out=.*(long|255)",
)

# ----------------------------------------------------------------------------- score / records
add(TB, "score-missing", ["score", "{case}/nope"], r"nope")
add(
    TB,
    "score-run-json-not-utf8",
    ["score", "{case}/run"],
    r"run\.json",
    setup=copy("run", "run", _bytes("run.json", b"\xff\xfe{")),
)
add(
    TB,
    "score-run-json-list",
    ["score", "{case}/run"],
    r"run\.json",
    setup=copy("run", "run", _bytes("run.json", b"[]")),
)
add(
    TB,
    "score-run-json-no-config",
    ["score", "{case}/run"],
    r"run\.json.*config",
    setup=copy("run", "run", edit_json("run.json", _del("config"))),
)
add(
    UW,
    "score-n-boot-huge",
    ["score", "{case}/run"],
    r"n_boot",
    setup=copy("run", "run", edit_json("run.json", _set("config.n_boot", 10**12))),
)
add(
    SA,
    "score-confidence-bad",
    ["score", "{case}/run"],
    r"confidence",
    setup=copy("run", "run", edit_json("run.json", _set("config.confidence", 7))),
)
add(
    SA,
    "score-seed-negative",
    ["score", "{case}/run"],
    r"seed",
    setup=copy("run", "run", edit_json("run.json", _set("config.seed", -4))),
)


def _records_edit(fn):
    def edit(root: Path) -> None:
        p = root / "episodes.jsonl"
        lines = [json.loads(x) for x in p.read_text().splitlines() if x.strip()]
        fn(lines)
        p.write_text("".join(json.dumps(x, allow_nan=True) + "\n" for x in lines))

    return edit


add(
    SA,
    "score-record-nan-return",
    ["score", "{case}/run"],
    r"episodes\.jsonl.*return",
    setup=copy("run", "run", _records_edit(lambda L: L[0].__setitem__("return", float("nan")))),
)
add(
    TB,
    "score-record-return-string",
    ["score", "{case}/run"],
    r"episodes\.jsonl.*return",
    setup=copy("run", "run", _records_edit(lambda L: L[0].__setitem__("return", "x"))),
)
add(
    TB,
    "score-record-missing-field",
    ["score", "{case}/run"],
    r"episodes\.jsonl.*(split|missing)",
    setup=copy("run", "run", _records_edit(lambda L: L[0].pop("split"))),
)
add(
    TB,
    "score-record-extra-field",
    ["score", "{case}/run"],
    r"episodes\.jsonl.*(bogus|unknown)",
    setup=copy("run", "run", _records_edit(lambda L: L[0].__setitem__("bogus", 1))),
)
add(
    TB,
    "score-record-not-object",
    ["score", "{case}/run"],
    r"episodes\.jsonl",
    setup=copy("run", "run", lambda r: (r / "episodes.jsonl").write_text("[1,2]\n" * 3)),
)
add(
    TB,
    "score-record-not-utf8",
    ["score", "{case}/run"],
    r"episodes\.jsonl",
    setup=copy("run", "run", lambda r: (r / "episodes.jsonl").write_bytes(b"\xff\xfe\n" * 3)),
)
add(
    SA,
    "score-record-success-string",
    ["score", "{case}/run"],
    r"episodes\.jsonl.*success",
    setup=copy("run", "run", _records_edit(lambda L: L[0].__setitem__("success_once", "yes"))),
)
add(
    SA,
    "score-record-negative-seed",
    ["score", "{case}/run"],
    r"episodes\.jsonl.*seed",
    setup=copy("run", "run", _records_edit(lambda L: L[0].__setitem__("seed", -1))),
)
add(
    SA,
    "score-record-negative-length",
    ["score", "{case}/run"],
    r"episodes\.jsonl.*length",
    setup=copy("run", "run", _records_edit(lambda L: L[0].__setitem__("length", -5))),
)
add(
    TB,
    "score-episodes-is-dir",
    ["score", "{case}/run"],
    r"episodes\.jsonl",
    setup=copy("run", "run", lambda r: ((r / "episodes.jsonl").unlink(), (r / "episodes.jsonl").mkdir())),
)

# ----------------------------------------------------------------------------- summaries / leaderboards / verdicts
SUMMARY_EDITS = {
    "ci-reversed": _set("splits.seen.success_once.mean.ci", [0.9, 0.1]),
    "rate-above-1": _set("splits.seen.success_once.mean.value", 1.5),
    "cell-rate-above-1": _set("cells.0.success_once.value", 2.0),
    "cell-ci-reversed": _set("cells.0.success_once.ci", [1.0, 0.0]),
    "value-outside-ci": _set("cells.0.success_once.value", 0.0001),
    "negative-seed": _set("provenance.seed", -3),
    "negative-episodes": _set("counts.episodes", -1),
    "successes-above-n": _set("cells.0.success_once.successes", 99),
    "nan-literal": _set("confidence", float("nan")),
    "inf-literal": _set("cells.0.success_once.value", float("inf")),
    "confidence-7": _set("confidence", 7),
    "schema-unknown": _set("schema", "bench.summary/9"),
    "schema-int": _set("schema", 3),
    "suite-not-object": _set("suite", "x"),
    "cells-not-list": _set("cells", {}),
    "n-negative": _set("cells.0.n", -2),
    "episode-seeds-negative": _set("provenance.episode_seeds", [-1]),
}
for name, fn in SUMMARY_EDITS.items():
    fam = TB if name in ("schema-int", "suite-not-object", "cells-not-list") else SA
    add(
        fam,
        f"validate-summary-{name}",
        ["leaderboard", "validate", "{case}/s.json"],
        r"s\.json",
        setup=copy("run/summary.json", "s.json", edit_json("", fn)),
    )
    add(
        fam,
        f"merge-summary-{name}",
        ["leaderboard", "merge", "{case}/s.json", "out={case}/out.json"],
        r"s\.json",
        setup=copy("run/summary.json", "s.json", edit_json("", fn)),
    )
    add(
        fam,
        f"report-summary-{name}",
        ["report", "{case}/s.json", "out={case}/rep"],
        r"s\.json",
        setup=copy("run/summary.json", "s.json", edit_json("", fn)),
    )
LB_EDITS = {
    "ci-reversed": _set("entries.0.score.ci", [0.9, 0.1]),
    "rate-above-1": _set("entries.0.score.value", 1.2),
    "entries-not-list": _set("entries", 5),
    "rank-zero": _set("entries.0.rank", 0),
    "nan": _set("entries.0.confidence", float("nan")),
    "suites-missing": _del("suites"),
}
for name, fn in LB_EDITS.items():
    add(
        SA,
        f"show-leaderboard-{name}",
        ["leaderboard", "show", "{case}/lb.json"],
        r"lb\.json",
        setup=copy("lb.json", "lb.json", edit_json("", fn)),
    )
    add(
        SA,
        f"merge-leaderboard-{name}",
        ["leaderboard", "merge", "{case}/lb.json", "out={case}/o.json"],
        r"lb\.json",
        setup=copy("lb.json", "lb.json", edit_json("", fn)),
    )
for name, data in [
    ("empty", b""),
    ("not-utf8", b"\xff\xfe\x00\x01"),
    ("truncated", b'{"schema": "bench.summ'),
    ("array", b"[1, 2]"),
    ("null", b"null"),
    ("deep", b"[" * 100000 + b"]" * 100000),
    ("huge-int", b'{"schema": "bench.summary/1", "confidence": 1' + b"0" * 5000 + b"}"),
]:
    add(TB, f"validate-{name}", ["leaderboard", "validate", "{case}/x.json"], r"x\.json", setup=write("x.json", data))
    add(TB, f"show-{name}", ["leaderboard", "show", "{case}/x.json"], r"x\.json", setup=write("x.json", data))
    add(TB, f"report-{name}", ["report", "{case}/x.json", "out={case}/r"], r"x\.json", setup=write("x.json", data))
add(TB, "validate-a-folder", ["leaderboard", "validate", "{case}"], r"case|folder|directory")
add(TB, "show-a-folder", ["leaderboard", "show", "{case}"], r"case|folder|directory")
add(TB, "merge-out-not-json", ["leaderboard", "merge", "{ws}/run", "out={case}/x.txt"], r"out=")
add(TB, "merge-unknown-key", ["leaderboard", "merge", "{ws}/run", "out={case}/x.json", "foo=1"], r"foo")
add(
    TB,
    "merge-out-in-missing-readonly",
    ["leaderboard", "merge", "{ws}/run", "out={case}/ro/x/y.json"],
    r"out=.*(writ|permission)",
    setup=lambda ws, c: ((c / "ro").mkdir(), (c / "ro").chmod(0o500)),
)
add(
    TB,
    "report-verdict-garbage",
    ["report", "{ws}/run", "out={case}/r", "verdict={case}/v.json"],
    r"v\.json",
    setup=write("v.json", b"\xff"),
)
add(
    TB,
    "report-verdict-is-summary",
    ["report", "{ws}/run", "out={case}/r", "verdict={ws}/run/summary.json"],
    r"verdict|summary",
)
add(
    TB,
    "report-calibration-garbage",
    ["report", "{ws}/run", "out={case}/r", "calibration={case}/c.json"],
    r"c\.json",
    setup=write("c.json", b'{"schema": "bench.calibration/1", "errors": 3}'),
)
add(
    TB,
    "report-calibration-nan",
    ["report", "{ws}/run", "out={case}/r", "calibration={case}/c.json"],
    r"c\.json",
    setup=write(
        "c.json",
        json.dumps(
            {"schema": "bench.calibration/1", "errors": {"nominal": {"free_run_nrmse": "x", "k_step_nrmse": None}}}
        ),
    ),
)
add(TB, "report-no-out", ["report", "{ws}/run"], r"out")
add(TB, "report-title-list", ["report", "{ws}/run", "out={case}/r", "title=[1,2]"], r"title")
add(
    TB,
    "report-run-videos-garbage",
    ["report", "{case}/run", "out={case}/r"],
    r"episodes\.jsonl",
    setup=copy("run", "run", lambda r: (r / "episodes.jsonl").write_text('{"run_id": 1}\n{"x": 2}\n')),
)

# ----------------------------------------------------------------------------- correlate
for name, data, match in [
    ("successes-above-trials", [{"policy": "a", "trials": 5, "successes": 9}], r"successes"),
    ("negative-trials", [{"policy": "a", "trials": -5, "successes": 0}], r"trials"),
    ("nan-successes", '[{"policy": "a", "trials": 5, "successes": NaN}]', r"successes|NaN"),
    ("string-trials", [{"policy": "a", "trials": "many", "successes": 1}], r"trials"),
    ("missing-policy", [{"trials": 5, "successes": 1}], r"policy"),
    ("not-list", {"a": 1}, r"sim"),
    ("empty-list", [], r"sim|policies"),
    (
        "duplicate-policy",
        [{"policy": "a", "trials": 5, "successes": 1}, {"policy": "a", "trials": 5, "successes": 2}],
        r"policy",
    ),
    ("huge-trials", [{"policy": "a", "trials": 10**30, "successes": 1}], r"trials"),
    ("bool-trials", [{"policy": "a", "trials": True, "successes": 1}], r"trials"),
]:
    body = data if isinstance(data, str) else json.dumps(data)
    add(
        SA if "above" in name or "duplicate" in name else TB,
        f"correlate-{name}",
        ["correlate", "sim={case}/s.json", "real={ws}/real.json"],
        match,
        setup=write("s.json", body),
    )
for name, body in [
    ("csv-garbage", "policy,trials\n\x00\x01,,,\n"),
    ("csv-not-utf8", b"\xff\xfe,,\n1,2,3\n"),
    ("csv-header-only", "policy,trials,successes\n"),
    ("csv-extra-cols", "policy,trials,successes\na,1,1,9\n"),
]:
    add(
        TB,
        f"correlate-{name}",
        ["correlate", "sim={case}/s.csv", "real={ws}/real.json"],
        r"s\.csv",
        setup=write("s.csv", body),
    )
for name, extra, match in [
    ("n-boot-huge", ["n_boot=1000000000000"], r"n_boot"),
    ("n-boot-zero", ["n_boot=0"], r"n_boot"),
    ("level-2", ["level=2"], r"level"),
    ("level-nan", ["level=nan"], r"level"),
    ("seed-negative", ["seed=-1"], r"seed"),
    ("same-file", [], r""),
]:
    args = ["correlate", "sim={ws}/sim.json", "real={ws}/real.json", *extra]
    if name == "same-file":
        continue
    add(UW if "huge" in name else SA, f"correlate-{name}", args, match)
add(TB, "correlate-missing-file", ["correlate", "sim={case}/nope.json", "real={ws}/real.json"], r"nope")
add(TB, "correlate-folder", ["correlate", "sim={case}", "real={ws}/real.json"], r"sim|case")
add(
    TB,
    "correlate-unknown-ext",
    ["correlate", "sim={case}/s.txt", "real={ws}/real.json"],
    r"s\.txt",
    setup=write("s.txt", "x"),
)

# ----------------------------------------------------------------------------- logs info (LeRobot metadata)
INFO_EDITS = {
    "fps-bool": _set("fps", True),
    "fps-negative": _set("fps", -10),
    "fps-absurd": _set("fps", 1e300),
    "fps-string": _set("fps", "10"),
    "fps-zero": _set("fps", 0),
    "shape-strings": _set("features/observation.state/shape", ["2"]),
    "shape-huge": _set("features/observation.state/shape", [10**12]),
    "shape-bool": _set("features/observation.state/shape", [True]),
    "shape-empty": _set("features/observation.state/shape", []),
    "dtype-unknown": _set("features/observation.state/dtype", "complex256"),
    "dtype-int": _set("features/observation.state/dtype", 5),
    "names-int": _set("features/observation.state/names", 7),
    "features-list": _set("features", []),
    "total-episodes-string": _set("total_episodes", "2"),
    "total-episodes-wrong": _set("total_episodes", 5),
    "total-frames-negative": _set("total_frames", -1),
    "codebase-int": _set("codebase_version", 3),
    "codebase-v2": _set("codebase_version", "v2.1"),
    "data-path-int": _set("data_path", 3),
    "data-path-escape": _set("data_path", "../../{chunk_index}{file_index}.parquet"),
    "data-path-format-key": _set("data_path", "data/{nope}.parquet"),
    "robot-type-list": _set("robot_type", [1]),
    "video-path-bad": _set("video_path", 5),
    "missing-fps": _del("fps"),
    "feature-not-object": _set("features/action", "float32"),
    "default-missing": _del("features/timestamp"),
}
for name, fn in INFO_EDITS.items():
    fam = UO if name.startswith("fps") or name.startswith("shape") else SA
    add(
        fam,
        f"info-{name}",
        ["logs", "info", "{case}/ds"],
        r"info\.json",
        setup=copy("ds", "ds", edit_json("meta/info.json", fn)),
    )
for name in ("data-path-escape", "shape-strings", "fps-bool", "dtype-unknown", "total-frames-negative"):
    add(
        TB,
        f"replay-info-{name}",
        ["replay", "logs={case}/ds", "spec={ws}/spec.yaml"],
        r"info\.json",
        setup=copy("ds", "ds", edit_json("meta/info.json", INFO_EDITS[name])),
    )
for name, data in [
    ("not-utf8", b"\xff\xfe"),
    ("empty", b""),
    ("truncated", b'{"codebase_version": "v3.0", "fp'),
    ("array", b"[]"),
    ("nan", b'{"fps": NaN}'),
]:
    add(
        TB,
        f"info-json-{name}",
        ["logs", "info", "{case}/ds"],
        r"info\.json",
        setup=copy("ds", "ds", _bytes("meta/info.json", data)),
    )
for rel, short in [
    ("meta/episodes/chunk-000/file-000.parquet", "episodes"),
    ("meta/tasks.parquet", "tasks"),
    ("data/chunk-000/file-000.parquet", "data"),
]:
    for keep in (0.0, 0.3, 0.9):
        add(
            TB,
            f"parquet-{short}-truncated-{keep}",
            ["logs", "info" if short != "data" else "card", "{case}/ds"],
            short if short != "episodes" else r"episodes|file-000",
            setup=copy("ds", "ds", _truncate(rel, keep)),
        )
    add(
        TB,
        f"parquet-{short}-garbage",
        ["logs", "card", "{case}/ds"],
        short if short != "episodes" else r"file-000",
        setup=copy("ds", "ds", _bytes(rel, b"PAR1" + b"\x00" * 100 + b"PAR1")),
    )
add(TB, "info-not-a-folder", ["logs", "info", "{ws}/data.csv"], r"data\.csv")
add(TB, "info-missing", ["logs", "info", "{case}/nope"], r"nope")
add(TB, "info-extra-arg", ["logs", "info", "{ws}/ds", "x"], r"one dataset folder|argument")


def _parquet_edit(rel: str, fn):
    def edit(root: Path) -> None:
        import pyarrow.parquet as pq

        p = root / rel
        table = pq.read_table(p)
        pq.write_table(fn(table), p)

    return edit


def _replace_col(name: str, values):
    def fn(table):
        import pyarrow as pa

        i = table.column_names.index(name)
        return table.set_column(i, name, pa.array(values(table)))

    return fn


EP = "meta/episodes/chunk-000/file-000.parquet"
DATA = "data/chunk-000/file-000.parquet"
for name, rel, fn, match in [
    ("ep-length-negative", EP, _replace_col("length", lambda t: [-1] * t.num_rows), r"length"),
    (
        "ep-index-strings",
        EP,
        _replace_col("episode_index", lambda t: [str(i) for i in range(t.num_rows)]),
        r"episode_index",
    ),
    ("ep-tasks-ints", EP, _replace_col("tasks", lambda t: [[1]] * t.num_rows), r"tasks"),
    (
        "ep-from-huge",
        EP,
        _replace_col("dataset_from_index", lambda t: [2**62] * t.num_rows),
        r"dataset_from_index|length",
    ),
    ("ep-chunk-negative", EP, _replace_col("data/chunk_index", lambda t: [-1] * t.num_rows), r"chunk_index"),
    ("ep-file-huge", EP, _replace_col("data/file_index", lambda t: [10**9] * t.num_rows), r"file_index|missing"),
    (
        "ep-meta-not-json",
        EP,
        lambda t: t.append_column("bench/meta", __import__("pyarrow").array(["{x"] * t.num_rows)),
        r"bench/meta",
    ),
    (
        "data-state-nan",
        DATA,
        _replace_col("observation.state", lambda t: [[float("nan"), 0.0]] * t.num_rows),
        r"observation\.state.*(NaN|inf)",
    ),
    (
        "data-state-strings",
        DATA,
        _replace_col("observation.state", lambda t: [["a", "b"]] * t.num_rows),
        r"observation\.state",
    ),
    (
        "data-timestamp-decreasing",
        DATA,
        _replace_col("timestamp", lambda t: [float(-i) for i in range(t.num_rows)]),
        r"timestamp",
    ),
    ("data-task-index-out", DATA, _replace_col("task_index", lambda t: [99] * t.num_rows), r"task_index"),
    ("data-action-wide", DATA, _replace_col("action", lambda t: [[0.0, 1.0, 2.0]] * t.num_rows), r"action"),
    ("data-action-inf", DATA, _replace_col("action", lambda t: [[float("inf")]] * t.num_rows), r"action"),
    (
        "data-extra-column",
        DATA,
        lambda t: t.append_column("zzz", __import__("pyarrow").array([1] * t.num_rows)),
        r"zzz",
    ),
]:
    cmd = ["logs", "card", "{case}/ds"]
    add(
        TB if "strings" in name or "huge" in name else SA,
        f"parquet-{name}",
        cmd,
        match,
        setup=copy("ds", "ds", _parquet_edit(rel, fn)),
    )

# ----------------------------------------------------------------------------- logs import
CSV_BAD = {
    "not-utf8": b"t,q\n\xff\xfe,1\n",
    "empty": b"",
    "header-only": b"t,q,u\n",
    "nan": b"t,q,u\n0,1,nan\n0.1,1,2\n",
    "string-value": b"t,q,u\n0,1,abc\n0.1,1,2\n",
    "ragged": b"t,q,u\n0,1\n0.1,1,2,3\n",
    "time-decreasing": b"t,q,u\n0.2,1,2\n0.1,1,2\n",
    "time-constant": b"t,q,u\n0.1,1,2\n0.1,1,2\n",
    "huge-value": b"t,q,u\n0,1e308,1\n0.1,1,2\n0.2,1,2\n",
    "duplicate-columns": b"t,q,q\n0,1,2\n0.1,1,2\n",
    "binary": bytes(range(256)) * 4,
    "time-huge": b"t,q,u\n0,1,1\n1e300,1,2\n",
    "one-row": b"t,q,u\n0,1,1\n",
}
for name, data in CSV_BAD.items():
    add(
        UO if name in ("huge-value", "time-huge") else TB,
        f"import-csv-{name}",
        ["logs", "import", "{case}/x.csv", "out={case}/out", "time=t"],
        r"x\.csv|fps|time",
        setup=write("x.csv", data),
    )
for name, extra, match in [
    ("fps-zero", ["fps=0"], r"fps"),
    ("fps-negative", ["fps=-1"], r"fps"),
    ("fps-nan", ["fps=nan"], r"fps"),
    ("fps-inf", ["fps=inf"], r"fps"),
    ("fps-absurd", ["fps=1e300"], r"fps"),
    ("fps-bool", ["fps=true"], r"fps"),
    ("fps-list", ["fps=[1]"], r"fps"),
    ("delimiter-empty", ["delimiter="], r"delimiter"),
    ("delimiter-long", ["delimiter=ab"], r"delimiter"),
    ("state-missing-col", ["state=[zz]"], r"zz"),
    ("state-dict", ["state={a: 1}"], r"state"),
    ("overwrite-string", ["overwrite=maybe"], r"overwrite"),
    ("unknown-key", ["frobnicate=1"], r"frobnicate"),
    ("format-bad", ["format=xls"], r"format"),
    ("episode-missing-col", ["episode=zz"], r"zz"),
    ("task-list", ["task=[a,b]"], r"task"),
    ("robot-type-dict", ["robot_type={a: 1}"], r"robot_type"),
    ("out-empty", ["out="], r"out"),
    ("time-and-fps-absurd", ["fps=100000000"], r"fps"),
]:
    add(
        UO if "absurd" in name else SA,
        f"import-{name}",
        ["logs", "import", "{ws}/data.csv", "out={case}/out", "time=t", *extra],
        match,
    )
add(SA, "import-no-out", ["logs", "import", "{ws}/data.csv"], r"out")
add(SA, "import-two-sources", ["logs", "import", "{ws}/data.csv", "{ws}/data.mat", "out={case}/o"], r"source")
add(SA, "import-missing-source", ["logs", "import", "{case}/nope.csv", "out={case}/o"], r"nope")
add(
    SA,
    "import-out-is-file",
    ["logs", "import", "{ws}/data.csv", "out={case}/f", "time=t"],
    r"out=.*(file|folder)",
    setup=write("f", "x"),
)
add(
    LB,
    "import-out-unwritable",
    ["logs", "import", "{ws}/data.csv", "out={case}/ro/out", "time=t"],
    r"out=.*(writ|permission)",
    setup=lambda ws, c: ((c / "ro").mkdir(), (c / "ro").chmod(0o500)),
)
MAT_BAD = {
    "garbage": b"MATLAB 5.0 MAT-file" + b"\x00" * 200,
    "random": bytes(range(256)) * 8,
    "hdf5": b"\x89HDF\r\n\x1a\n" + b"\x00" * 600,
    "empty": b"",
}
for name, data in MAT_BAD.items():
    add(
        TB,
        f"import-mat-{name}",
        ["logs", "import", "{case}/x.mat", "out={case}/out"],
        r"x\.mat",
        setup=write("x.mat", data),
    )


def _savemat(variables):
    def setup(ws: Path, case: Path) -> None:
        import numpy as np
        import scipy.io

        scipy.io.savemat(
            case / "x.mat", {k: (np.asarray(v) if not isinstance(v, str) else v) for k, v in variables.items()}
        )

    return setup


add(
    TB,
    "import-mat-truncated",
    ["logs", "import", "{case}/data.mat", "out={case}/out"],
    r"data\.mat",
    setup=copy("data.mat", "data.mat", _truncate("", 0.5)),
)
add(
    TB,
    "import-mat-strings",
    ["logs", "import", "{case}/x.mat", "out={case}/out", "state=[s]"],
    r"\bs\b",
    setup=_savemat({"t": [[0.0], [0.1], [0.2]], "s": "hello"}),
)
add(
    TB,
    "import-mat-complex",
    ["logs", "import", "{case}/x.mat", "out={case}/out", "state=[z]"],
    r"\bz\b",
    setup=_savemat({"t": [[0.0], [0.1], [0.2]], "z": [[1 + 2j], [1j], [2]]}),
)
add(
    TB,
    "import-mat-nan",
    ["logs", "import", "{case}/x.mat", "out={case}/out", "state=[q]"],
    r"\bq\b",
    setup=_savemat({"t": [[0.0], [0.1], [0.2]], "q": [[1.0], [float("nan")], [2]]}),
)
add(
    TB,
    "import-mat-3d",
    ["logs", "import", "{case}/x.mat", "out={case}/out", "state=[q]"],
    r"\bq\b",
    setup=_savemat({"t": [[0.0], [0.1], [0.2]], "q": [[[1.0, 2.0]] * 3] * 3}),
)
add(
    TB,
    "import-mat-scalar-nan-meta",
    ["logs", "import", "{case}/x.mat", "out={case}/out", "state=[q]"],
    r"\bk\b|meta|NaN",
    setup=_savemat({"t": [[0.0], [0.1], [0.2]], "q": [[1.0], [2.0], [3.0]], "k": [[float("nan")]]}),
)
add(
    TB,
    "import-mat-velocity-string",
    ["logs", "import", "{ws}/data.mat", "out={case}/out", "velocity=sometimes"],
    r"velocity",
)
add(TB, "import-mat-time-missing", ["logs", "import", "{ws}/data.mat", "out={case}/out", "time=zz"], r"zz")
add(
    TB,
    "import-mat-huge-values",
    ["logs", "import", "{case}/x.mat", "out={case}/out", "state=[q]"],
    r"\bq\b",
    setup=_savemat({"t": [[0.0], [0.1], [0.2]], "q": [[1.0], [1e300], [2]]}),
)


def _tfrecord(records: list[bytes], crc: bool = True) -> bytes:
    from bench.logs.tfrecord import masked_crc32c

    out = b""
    for r in records:
        head = struct.pack("<Q", len(r))
        out += (
            head
            + struct.pack("<I", masked_crc32c(head) if crc else 0)
            + r
            + struct.pack("<I", masked_crc32c(r) if crc else 0)
        )
    return out


def _rlds_edit(fn):
    def edit(root: Path) -> None:
        shard = next(root.rglob("*.tfrecord*"))
        fn(root, shard)

    return edit


RLDS = ["logs", "import", "{case}/rlds", "out={case}/out", "format=rlds", "fps=5"]
for name, fn, match in [
    ("shard-truncated", lambda r, s: s.write_bytes(s.read_bytes()[:100]), r"tfrecord"),
    ("shard-bad-crc", lambda r, s: s.write_bytes(s.read_bytes()[:20] + b"\x00" * 8 + s.read_bytes()[28:]), r"tfrecord"),
    (
        "shard-huge-length",
        lambda r, s: s.write_bytes(
            _tfrecord([b"x"], crc=False).replace(struct.pack("<Q", 1), struct.pack("<Q", 2**60), 1)
        ),
        r"tfrecord",
    ),
    ("shard-garbage-record", lambda r, s: s.write_bytes(_tfrecord([b"\xff" * 40])), r"tfrecord|Example"),
    ("shard-empty", lambda r, s: s.write_bytes(b""), r"tfrecord|records"),
    ("features-not-json", lambda r, s: (s.parent / "features.json").write_bytes(b"\xff{"), r"features\.json"),
    ("features-list", lambda r, s: (s.parent / "features.json").write_text("[]"), r"features\.json"),
    (
        "features-huge-shape",
        lambda r, s: (s.parent / "features.json").write_text(
            (s.parent / "features.json").read_text().replace('"7"', '"1000000000000"')
        ),
        r"features\.json|shape",
    ),
    (
        "features-bad-dtype",
        lambda r, s: (s.parent / "features.json").write_text(
            (s.parent / "features.json").read_text().replace('"float32"', '"floaty"')
        ),
        r"features\.json|dtype",
    ),
]:
    add(
        UW if "huge" in name else TB,
        f"import-rlds-{name}",
        RLDS,
        match,
        setup=copy("rlds", "rlds", _rlds_edit(fn)),
        needs=("rlds",),
    )
add(SA, "import-rlds-no-fps", ["logs", "import", "{ws}/rlds", "out={case}/out", "format=rlds"], r"fps", needs=("rlds",))
add(
    SA,
    "import-rlds-bad-split",
    ["logs", "import", "{ws}/rlds", "out={case}/out", "format=rlds", "fps=5", "split=nope"],
    r"split",
    needs=("rlds",),
)
add(
    SA,
    "import-rlds-state-missing",
    ["logs", "import", "{ws}/rlds", "out={case}/out", "format=rlds", "fps=5", "state=observation/nope"],
    r"state",
    needs=("rlds",),
)

# ----------------------------------------------------------------------------- logs card / rank
for name, extra, match in [
    ("episodes-negative", ["episodes=-1"], r"episodes"),
    ("dup-tol-nan", ["dup_tol=nan"], r"dup_tol"),
    ("dup-tol-inf", ["dup_tol=inf"], r"dup_tol"),
    ("seed-string", ["seed=x"], r"seed"),
    ("unknown", ["foo=1"], r"foo"),
    ("out-existing", ["out={ws}/lb.json"], r"out="),
    ("episodes-huge", ["suite=tests.toy_suite:ToySuite", "episodes=1000000000"], r"episodes"),
    ("out-dir", ["out={case}"], r"out="),
]:
    add(UW if "huge" in name else SA, f"card-{name}", ["logs", "card", "{ws}/ds", *extra], match)
add(TB, "rank-calibration-missing", ["logs", "rank", "{ws}/ds", "calibration={case}/nope.json"], r"nope|calibration")
add(
    TB,
    "rank-calibration-garbage",
    ["logs", "rank", "{ws}/ds", "calibration={case}/c.json"],
    r"c\.json",
    setup=write("c.json", b"\xff"),
)
add(
    TB,
    "rank-calibration-wrong-schema",
    ["logs", "rank", "{ws}/ds", "calibration={ws}/lb.json"],
    r"lb\.json|calibration",
)
add(SA, "rank-top-negative", ["logs", "rank", "{ws}/ds", "calibration={ws}/lb.json", "top=-1"], r"top")
add(
    SA,
    "rank-horizon-bad",
    ["logs", "rank", "{ws}/ds", "calibration={ws}/lb.json", "horizon=forever"],
    r"horizon|lb\.json",
)

# ----------------------------------------------------------------------------- replay
REPLAY = ["replay", "logs={ws}/ds", "spec={ws}/spec.yaml"]
for name, extra, match in [
    ("k-zero", ["k=0"], r"\bk\b"),
    ("k-negative", ["k=-1"], r"\bk\b"),
    ("k-huge", ["k=1000000000000"], r"\bk\b"),
    ("threads-zero", ["threads=0"], r"threads"),
    ("threads-huge", ["threads=1000000"], r"threads"),
    ("plot-negative", ["plot=-1"], r"plot"),
    ("plot-huge", ["plot=1000000"], r"plot"),
    ("episodes-negative", ["episodes=[-1]"], r"episodes"),
    ("episodes-out", ["episodes=[99]"], r"episodes"),
    ("episodes-dup", ["episodes=[0,0]"], r"episodes"),
    ("commands-bad", ["commands=torque"], r"commands"),
    ("spec-and-suite", ["suite=held_out_robots"], r"spec|suite"),
    ("k-float", ["k=2.5"], r"\bk\b"),
]:
    add(UW if "huge" in name else SA, f"replay-{name}", [*REPLAY, *extra], match)
add(SA, "replay-no-logs", ["replay", "spec={ws}/spec.yaml"], r"logs")
add(SA, "replay-logs-missing", ["replay", "logs={case}/nope", "spec={ws}/spec.yaml"], r"nope")
SPEC_BAD = {
    "not-utf8": b"\xff\xfe: x",
    "empty": b"",
    "list": b"- 1\n- 2\n",
    "yaml-bomb": b"a: &a [1,1,1,1,1,1,1,1,1]\nb: &b [*a,*a,*a,*a,*a,*a,*a,*a,*a]\nc: &c [*b,*b,*b,*b,*b,*b,*b,*b,*b]\n"
    b"d: &d [*c,*c,*c,*c,*c,*c,*c,*c,*c]\ne: &e [*d,*d,*d,*d,*d,*d,*d,*d,*d]\nf: [*e,*e,*e,*e,*e,*e,*e,*e]\n",
    "model-missing": b"model: nope.xml\nsignals: {qpos: {column: observation.state, index: [0]}, ctrl: {column: action, index: [0]}}\n",
    "model-not-xml": b"model: spec.yaml\nsignals: {qpos: {column: observation.state, index: [0]}, ctrl: {column: action, index: [0]}}\n",
}


def _spec(text: str):
    def setup(ws: Path, case: Path) -> None:
        (case / "arm.xml").write_text((ws / "arm.xml").read_text())
        (case / "spec.yaml").write_text(text)

    return setup


for name, data in SPEC_BAD.items():
    add(
        TB,
        f"replay-spec-{name}",
        ["replay", "logs={ws}/ds", "spec={case}/spec.yaml"],
        r"spec|model|nope",
        setup=write("spec.yaml", data) if name != "model-not-xml" else _spec(data.decode()),
    )
BASE_SPEC = SPEC_YAML
SPEC_EDITS = {
    "substeps-zero": ("substeps: 10", "substeps: 0"),
    "substeps-huge": ("substeps: 10", "substeps: 100000000000"),
    "substeps-nan": ("substeps: 10", "substeps: .nan"),
    "index-negative": ("index: [0]}\n  qvel", "index: [-1]}\n  qvel"),
    "index-out": ("index: [0]}\n  qvel", "index: [7]}\n  qvel"),
    "column-missing": ("column: observation.state, index: [0]", "column: nope, index: [0]"),
    "index-string": ("index: [0]}\n  qvel", "index: [a]}\n  qvel"),
    "bounds-reversed": ("bounds: [0.01, 5]", "bounds: [5, 0.01]"),
    "bounds-nan": ("bounds: [0.01, 5]", "bounds: [.nan, 5]"),
    "bounds-inf": ("bounds: [0.01, 5]", "bounds: [0.01, .inf]"),
    "int-field": ("field: dof_damping", "field: jnt_qposadr"),
    "int-field-bodyid": ("field: dof_damping", "field: dof_bodyid"),
    "int-field-type": ("field: dof_damping", "field: jnt_type"),
    "field-unknown": ("field: dof_damping", "field: dof_nope"),
    "element-unknown": ("elements: [j1]", "elements: [j9]"),
    "holdout-2": ("holdout: 0.5", "holdout: 2"),
    "holdout-string": ("holdout: 0.5", "holdout: half"),
    "effects-unknown": ("effects: none", "effects: [teleport]"),
    "unknown-field": ("holdout: 0.5", "holdout: 0.5\nfrobnicate: 1"),
    "model-is-dir": ("model: arm.xml", "model: ."),
    "threads-huge": ("holdout: 0.5", "holdout: 0.5\nthreads: 100000"),
    "horizon-huge": ("holdout: 0.5", "holdout: 0.5\nhorizon: 1e300"),
    "init-outside": ("bounds: [0.01, 5]", "bounds: [0.01, 5], init: 9"),
}
for name, (old, new) in SPEC_EDITS.items():
    text = BASE_SPEC.replace(old, new)
    assert text != BASE_SPEC, name
    fam = UW if "huge" in name else SA
    add(
        fam,
        f"calibrate-spec-{name}",
        ["calibrate", "spec={case}/spec.yaml", "logs={ws}/ds", "out={case}/out", "residual=false", "quiet=true"],
        r"spec|params|field|bounds|holdout|substeps"
        r"|index|column|effects|model|threads|horizon|init",
        setup=_spec(text),
    )
    if name in ("substeps-zero", "substeps-huge", "index-negative", "index-out", "column-missing", "model-is-dir"):
        add(
            fam,
            f"replay-spec-{name}",
            ["replay", "logs={ws}/ds", "spec={case}/spec.yaml", "out={case}/out"],
            r"spec|substeps|index|column|model",
            setup=_spec(text),
        )
for name, extra, match in [
    ("threads-zero", ["threads=0"], r"threads"),
    ("threads-huge", ["threads=100000"], r"threads"),
    ("seed-negative", ["seed=-1"], r"seed"),
    ("effects-unknown", ["effects=[x]"], r"effects"),
    ("residual-string", ["residual=maybe"], r"residual"),
    ("unknown", ["frob=1"], r"frob"),
    ("quiet-string", ["quiet=loud"], r"quiet"),
    ("logs-missing", ["logs={case}/nope"], r"nope"),
]:
    args = ["calibrate", "spec={ws}/spec.yaml", "logs={ws}/ds", "out={case}/out", "residual=false", "quiet=true"]
    args = [a for a in args if a.split("=")[0] not in [e.split("=")[0] for e in extra]] + extra
    add(UW if "huge" in name else SA, f"calibrate-{name}", args, match)
for name, extra, match in [
    ("episodes-huge", ["episodes=1000000000"], r"episodes"),
    ("duration-huge", ["duration=1e12"], r"duration"),
    ("fps-huge", ["fps=1e12"], r"fps"),
    ("fps-nan", ["fps=nan"], r"fps"),
    ("duration-inf", ["duration=inf"], r"duration"),
    ("effect-unknown", ["effect=teleport"], r"effect"),
    ("seed-negative", ["seed=-1"], r"seed"),
]:
    args = ["calibrate", "generate", "effect=none", "out={case}/g", "episodes=2", "duration=1"]
    args = [a for a in args if a.split("=")[0] not in [e.split("=")[0] for e in extra]] + extra
    add(UW if "huge" in name or "inf" in name else SA, f"generate-{name}", args, match)

# ----------------------------------------------------------------------------- actions / coverage / regress
for name, extra, match in [
    ("n-boot-huge", ["n_boot=1000000000000"], r"n_boot"),
    ("confidence-2", ["confidence=2"], r"confidence"),
    ("seed-negative", ["seed=-1"], r"seed"),
    ("no-logs", [], r"logs"),
    ("episodes-negative", ["episodes=[-1]"], r"episodes"),
]:
    args = ["actions", *(["logs={ws}/ds"] if name != "no-logs" else []), "suite=tests.toy_suite:ToySuite", *extra]
    add(UW if "huge" in name else SA, f"actions-{name}", args, match)
for name, extra, match in [
    ("quantile-2", ["quantile=2"], r"quantile"),
    ("episodes-huge", ["episodes=1000000000"], r"episodes"),
    ("horizon-huge", ["horizon=100000000"], r"horizon"),
    ("seed-negative", ["seed=-1"], r"seed"),
    ("data-missing", ["data={case}/nope"], r"nope"),
    ("quantile-nan", ["quantile=nan"], r"quantile"),
]:
    args = ["coverage", "suite=tests.toy_suite:ToySuite", *([] if "data" in name else ["data={ws}/ds"]), *extra]
    add(UW if "huge" in name else SA, f"coverage-{name}", args, match)
for name, extra, match in [
    ("margin-nan", ["margin=nan"], r"margin"),
    ("alpha-2", ["alpha=2"], r"alpha"),
    ("batch-negative", ["batch=-1"], r"batch"),
    ("candidate-missing", ["baseline=scripted"], r"candidate"),
    ("margin-negative", ["margin=-1"], r"margin"),
]:
    args = ["regress", TOY, "candidate=scripted", "baseline=random", "runs={case}/runs", *extra]
    args = [a for a in args if not (name == "candidate-missing" and a.startswith(("candidate=", "baseline=")))]
    add(SA, f"regress-{name}", args, match)

# ----------------------------------------------------------------------------- python -m baselines.bc
BC = ["data=[{ws}/ds]", "out={case}/p.safetensors"]
for name, extra, match in [
    ("epochs-negative", ["epochs=-1"], r"epochs"),
    ("lr-nan", ["lr=nan"], r"\blr\b"),
    ("batch-zero", ["batch_size=0"], r"batch_size"),
    ("hidden-zero", ["hidden=[0]"], r"hidden"),
    ("threads-huge", ["threads=1000000"], r"threads"),
    ("epochs-huge", ["epochs=1000000000"], r"epochs"),
    ("out-suffix", ["out={case}/p.txt"], r"out"),
    ("data-missing", ["data=[{case}/nope]"], r"nope"),
    ("seed-negative", ["seed=-1"], r"seed"),
    ("hidden-huge", ["hidden=[100000000]"], r"hidden"),
    ("activation-bad", ["activation=x"], r"activation"),
    ("noise-inf", ["obs_noise=inf"], r"obs_noise"),
]:
    args = [a for a in BC if a.split("=")[0] not in [e.split("=")[0] for e in extra]] + extra
    add(UW if "huge" in name else SA, f"bc-{name}", args, match, main="baselines.bc")

# ----------------------------------------------------------------------------- misc commands
add(SA, "check-unknown-suite", ["check", "suite=nope"], r"nope")
add(SA, "perf-bad-key", ["perf", "frob=1"], r"frob")
add(SA, "list-extra", ["list", "extra"], r"extra|list")
add(SA, "unknown-command", ["frobnicate"], r"frobnicate")
add(SA, "logs-unknown-sub", ["logs", "frob"], r"frob")
add(SA, "leaderboard-unknown-sub", ["leaderboard", "frob"], r"frob")
add(SA, "calibrate-unknown-positional", ["calibrate", "frob"], r"frob")


# ----------------------------------------------------------------------------- issue 28's families
CAP, NM, SLOW, SHORT, BOUNDS = (
    "capability missing",
    "nothing measured",
    "slow servers",
    "short episodes",
    "physically impossible bounds",
)


def unlimited(family: str, name: str, argv: list[str], match: str, **kw) -> None:
    """`add` without the address-space limit: these cases start threads (a run's progress ticker, a remote
    policy's wait reports) and MuJoCo models, which fail with "can't start new thread" or "could not allocate
    memory" under the corpus' 4 GB limit once a long corpus run has loaded the simulators."""
    add(family, name, argv, match, **{"memory_gb": None, **kw})


MS = ["run", "suite=maniskill_tasks", "tasks=[PickCube]", "policy=random", "episodes=1", "workers=1"]
unlimited(
    CAP,
    "cap-maniskill-cameras-without-vulkan",
    [*MS, "obs=rgb", "out={case}/runs"],
    r"obs=rgb: ManiSkill cameras need a Vulkan device .*fetch_lavapipe\.sh",
    needs=("no-vulkan",),
    timeout=120,
)
unlimited(
    CAP,
    "cap-maniskill-gpu-backend",
    [*MS, "sim_backend=physx_cuda", "out={case}/runs"],
    r"sim_backend=physx_cuda: .*use sim_backend=physx_cpu",
    needs=("no-physx-gpu",),
    timeout=120,
)
unlimited(
    CAP,
    "cap-visual-axis-on-a-state-only-policy",
    ["run", "policy=bc", "robots=[Panda]", "obs=state+rgb", "perturb.light=[0.3]", "episodes=1", "out={case}/runs"],
    r"perturb\.light changes only camera images, and policy 'bc' reads none",
    timeout=120,
)
unlimited(
    CAP,
    "cap-remote-nothing-listening",
    [*RUN, "policy=remote", "port=1", "warmup_s=1"],
    r"policy=remote: no policy server at 127\.0\.0\.1:1: connection refused",
)
unlimited(CAP, "cap-toy-policy-needs-a-camera", [*RUN, "policy=tests.toy_suite:NeedsCamera"], r"needs observation keys")

# nothing measured: the run, score or gate writes what it measured (records, summary) and exits 3
TOY_RUN = [TOY, "workers=1", "episodes=1", "n_boot=200", "out={case}/runs", "run_id=r"]
unlimited(
    NM,
    "nm-every-episode-errors",
    ["run", *TOY_RUN, "fault=raise", "robots=[c]"],
    r"run r .*no episode completed: all 1 errored.*RuntimeError: toy env exploded",
    code=3,
    allowed=("{case}/runs",),
)
unlimited(
    NM,
    "nm-one-cell-of-three-empty",
    ["run", *TOY_RUN, "fault=nan_reward"],
    r"1 of 3 cells completed no episode \(reach/c/line\) while the others did; error: non-finite reward",
    code=3,
    allowed=("{case}/runs",),
)
unlimited(
    NM,
    "nm-score-of-an-empty-run",
    ["score", "{case}/run"],
    r"episodes\.jsonl holds no episode record",
    setup=copy("run", "run", _bytes("episodes.jsonl", b"")),
    code=3,
    allowed=("{case}/run/summary.json",),
)


def _errored(robot: str):
    def edit(root: Path) -> None:
        p = root / "episodes.jsonl"
        recs = [json.loads(line) for line in p.read_text().splitlines()]
        for r in recs:
            if r["robot"] == robot:
                r.update(error="RuntimeError: simulator lost", success_once=False, success_at_end=False)
        p.write_text("".join(json.dumps(r) + "\n" for r in recs))

    return edit


GATE_OUT = ("{case}/g", "{case}/v.json", "{case}/v.junit.xml", "{case}/v.md")
unlimited(
    NM,
    "nm-gate-against-a-baseline-that-measured-nothing-in-a-cell",
    [
        "regress",
        "candidate=scripted",
        "baseline={case}/base",
        "workers=1",
        "runs={case}/g",
        "run_id=g",
        "out={case}/v.json",
    ],
    r"regress g: the baseline completed no episode in 1 of 3 cells \(reach/b/line\).*simulator lost",
    setup=copy("run", "base", _errored("b")),
    code=3,
    allowed=GATE_OUT,
)
unlimited(
    NM,
    "nm-remote-server-that-never-warms-up",
    ["run", *TOY_RUN, "robots=[a]", "policy=remote", "port={port:stall_openpi}", "warmup_s=0.5"],
    r"no episode completed.*building env/policy failed: RemoteError: the server at 127\.0\.0\.1:\d+ did not "
    r"answer within warmup_s=0\.5 s",
    code=3,
    allowed=("{case}/runs",),
)

# slow servers: set-up is bounded by warmup_s (not timeout_s); one that never answers is one line
REMOTE = [*RUN, "policy=remote"]
unlimited(
    SLOW,
    "slow-server-hangs-at-the-handshake",
    [*REMOTE, "port={port:hang}", "warmup_s=1"],
    r"policy=remote: the server at 127\.0\.0\.1:\d+ accepted the connection but did not answer the websocket "
    r"handshake within warmup_s=1 s",
)
unlimited(
    SLOW,
    "slow-server-never-answers-the-check",
    [*REMOTE, "port={port:stall}", "warmup_s=1"],
    r"policy=remote: the server at 127\.0\.0\.1:\d+ did not answer within warmup_s=1 s",
)
unlimited(SLOW, "slow-warmup-zero", [*REMOTE, "warmup_s=0"], r"warmup_s=0\.0: must be > 0")
unlimited(SLOW, "slow-warmup-huge", [*REMOTE, "warmup_s=1e9"], r"warmup_s=1000000000\.0: must be > 0 and at most 3600")
unlimited(SLOW, "slow-warmup-nan", [*REMOTE, "warmup_s=nan"], r"warmup_s")
unlimited(SLOW, "slow-timeout-negative", [*REMOTE, "timeout_s=-1"], r"timeout_s=-1\.0: must be > 0")

# short episodes: shorter than k is measured (to each episode's end); shorter than the minimum is refused
unlimited(
    SHORT,
    "short-replay-k-longer-than-every-episode",
    ["replay", "logs={ws}/ds", "spec={ws}/spec.yaml", "k=1000", "out={case}/r"],
    r"",
    code=0,
    allowed=("{case}/r",),
)


def _short_logs(frames: int):
    def setup(ws: Path, case: Path) -> None:
        from hostile import _arm_logs

        _arm_logs(case / "ds", episodes=2, frames=frames)

    return setup


unlimited(
    SHORT,
    "short-replay-episodes-below-the-minimum",
    ["replay", "logs={case}/ds", "spec={ws}/spec.yaml"],
    r"episode 0 has 3 frames; replay and calibration need at least 4",
    setup=_short_logs(3),
)
unlimited(
    SHORT,
    "short-replay-episodes-of-five-frames-k-10",
    ["replay", "logs={case}/ds", "spec={ws}/spec.yaml", "k=10", "out={case}/r"],
    r"",
    setup=_short_logs(5),
    code=0,
    allowed=("{case}/r",),
)
unlimited(
    SHORT,
    "short-calibrate-horizon-longer-than-the-episodes",
    ["calibrate", "spec={case}/spec.yaml", "logs={ws}/ds", "out={case}/cal"],
    r"",
    setup=_spec(SPEC_YAML + "horizon: 100\n"),
    code=0,
    allowed=("{case}/cal",),
)

# physically impossible bounds: a spec whose bounds let a mass, a damping, a friction ... leave physics
for name, param, match in [
    ("mass-negative", "{name: m, field: body_mass, elements: [link1], bounds: [-5, -1]}", r"body_mass go negative"),
    ("mass-crossing-zero", "{name: m, field: body_mass, elements: [link1], bounds: [-1, 2]}", r"go negative"),
    ("damping-negative", "{name: d, field: dof_damping, elements: [j1], bounds: [-0.5, 5]}", r"dof_damping go neg"),
    ("armature-negative", "{name: a, field: dof_armature, elements: [j1], bounds: [-1, 0.1]}", r"an armature"),
    ("inertia-negative", "{name: i, field: body_inertia, elements: [link1], bounds: [-1, 1]}", r"an inertia"),
    ("frictionloss-negative", "{name: f, field: dof_frictionloss, elements: [j1], bounds: [-1, 1]}", r"friction"),
    ("stiffness-negative", "{name: k, field: jnt_stiffness, elements: [j1], bounds: [-3, -1]}", r"joint stiffness"),
    (
        "damping-scale-negative",
        "{name: d, field: dof_damping, elements: [j1], bounds: [-1, 2], scale: true}",
        r"the factor on dof_damping go negative",
    ),
]:
    add(
        BOUNDS,
        f"bounds-{name}",
        ["calibrate", "spec={case}/spec.yaml", "logs={ws}/ds", "out={case}/cal"],
        rf"params\[0\]\.bounds.*{match}",
        setup=_spec(SPEC_YAML.replace("{name: damping, field: dof_damping, elements: [j1], bounds: [0.01, 5]}", param)),
    )
for name, effect, match in [
    ("friction-negative", "{name: coulomb_friction, bounds: [-1, 1]}", r"coulomb_friction's friction go negative"),
    ("delay-negative", "{name: actuator_delay, bounds: [-0.1, 0.1]}", r"actuator_delay's delay go negative"),
    ("share-above-one", "{name: torque_saturation, bounds: [0, 2]}", r"clipped_share go above 1"),
    ("payload-negative", "{name: payload_mass, bounds: [-2, 0]}", r"payload_mass's mass go negative"),
    ("deadband-negative", "{name: deadband, bounds: [-1, 1]}", r"deadband's deadband go negative"),
]:
    add(
        BOUNDS,
        f"bounds-effect-{name}",
        ["calibrate", "spec={case}/spec.yaml", "logs={ws}/ds", "out={case}/cal"],
        rf"effects\[0\]\.bounds.*{match}",
        setup=_spec(SPEC_YAML.replace("effects: none", f"effects: [{effect}]")),
    )


# Cases kept in modules of their own (one per owner) register through `add` as well.
def _load_extra_cases() -> None:
    import importlib

    for name in ("hostile_corpus_readers", "hostile_corpus_grammar"):
        try:
            importlib.import_module(name)
        except ModuleNotFoundError as exc:
            if exc.name != name:
                raise


_load_extra_cases()
