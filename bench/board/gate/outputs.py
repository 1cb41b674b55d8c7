"""What the regression gate shows and leaves for CI: terminal tables, JUnit XML, a Markdown summary.

All three are views of the verdict document (`bench.regress/2`, built by `bench.cli.regress`):
nothing here decides anything. Beside `verdict.json` the gate writes `verdict.junit.xml`
(one test case per cell, one per aggregate test, one for the verdict; a CI's test reporter
shows the regressed cells as failed tests) and `verdict.md` (for a job's step summary,
e.g. `cat verdict.md >> "$GITHUB_STEP_SUMMARY"`).
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import TYPE_CHECKING, Any

from bench.core.console import table_console
from bench.core.io import write_atomic, write_text_atomic
from bench.core.schema import validate

if TYPE_CHECKING:
    from rich.console import Console

VERDICT_WORDS = {
    "regression": "REGRESSION",
    "no_regression": "NO REGRESSION",
    "inconclusive": "INCONCLUSIVE",
    "nothing_measured": "NOTHING MEASURED",
}


def output_paths(verdict: Path) -> dict[str, Path]:
    """The files written beside the verdict JSON: X.json -> X.junit.xml and X.md."""
    return {"verdict": verdict, "junit": verdict.with_suffix(".junit.xml"), "markdown": verdict.with_suffix(".md")}


def cell_name(c: dict[str, Any]) -> str:
    """`Lift/Panda/default` (plus ` condition` when it is not nominal)."""
    name = f"{c['task']}/{c['robot']}/{c['env']}"
    return name if c["condition"] == "nominal" else f"{name} {c['condition']}"


def _bounds(row: dict[str, Any], lo: str = "drop_lcb", hi: str = "drop_ucb") -> str:
    if row.get(lo) is None:
        return "n/a"
    return f"[{row[lo]:+.2f}, {row[hi]:+.2f}]"


def regressed_line(doc: dict[str, Any]) -> str:
    """One line naming what regressed, e.g. `cell Lift/Panda/default: drop +0.60 [+0.31, +0.80]`."""
    parts = [
        f"{r['kind']} {r['name']}: drop {r['drop']:+.2f} [{r['lcb']:+.2f}, {r['ucb']:+.2f}]"
        for r in doc.get("regressed", [])
    ]
    return "; ".join(parts)


def look_line(look: dict[str, Any], n_looks: int) -> str:
    """Progress line printed after each look."""
    if "mean" not in look:
        return f"look {look['look']}/{n_looks}: {look.get('reason', 'no pairs')}"
    m, q = look["mean"], look["iqm"]
    flagged = f" regressed: {', '.join(look['regressed'])}" if look["regressed"] else ""
    return (
        f"look {look['look']}/{n_looks} ({look['episodes_per_cell']} ep/cell, {look['pairs']} pairs): "
        f"drop {m['value']:+.3f} (LCB {m['lcb']:+.3f}, certify UCB {m['ucb']:+.3f}), IQM drop {q['value']:+.3f}"
        f"{flagged} -> {look['decision']}"
    )


def render(doc: dict[str, Any], console: Console | None = None) -> None:
    """The per-cell and per-split tables, the looks and the verdict, in the terminal."""
    from rich.table import Table  # rich: loaded only when something is drawn on the terminal

    console = console or table_console()
    if doc.get("identical"):
        console.print(f"[bold green]NO REGRESSION[/] (exit {doc['exit_code']}): {doc['note']}")
        return
    t = Table(
        title=f"regress · {doc['suite']['name']} v{doc['suite']['version']} · metric {doc['metric']} · "
        f"candidate {doc['candidate']['spec']} vs baseline {doc['baseline']['spec']}",
        title_justify="left",
    )
    unpaired = doc.get("pairing") == "unpaired"  # bench.board.gate.unpaired: episodes, not pairs
    cols: tuple[str, ...] = (
        "cell",
        "split",
        "pairs",
        "baseline",
        "candidate",
        "drop",
        "bounds",
        "p",
        "lost/won",
        "regressed",
    )
    if unpaired:
        cols = tuple({"pairs": "episodes", "lost/won": "base/cand ep"}.get(c, c) for c in cols)
    for col in cols:
        t.add_column(col, justify="left" if col in ("cell", "split", "regressed") else "right", no_wrap=True)
    for c in doc["cells"]:
        t.add_row(
            cell_name(c),
            c["split"],
            str(c["pairs"]),
            f"{c['baseline'] * 100:.0f}%",
            f"{c['candidate'] * 100:.0f}%",
            f"{c['drop']:+.2f}",
            _bounds(c),
            "n/a" if c["p"] is None else f"{c['p']:.2g}",
            f"{c['episodes_baseline']} / {c['episodes_candidate']}"
            if unpaired
            else f"{c['baseline_only']} / {c['candidate_only']}",
            "YES" if c["regressed"] else ("" if c["tested"] else "untested"),
            style="red" if c["regressed"] else None,
        )
    console.print(t)
    if any(not c["tested"] for c in doc["cells"]):
        console.print(
            "untested: too few pairs for the cell's own test to reach its share of alpha (the pooled, "
            "split and IQM tests still cover it); bounds: one-sided each, at the test's level"
        )
    if len(doc["splits"]) > 1:
        s = Table(title="splits", title_justify="left")
        for col in ("split", "cells", "pairs", "baseline", "candidate", "drop", "bounds", "regressed"):
            s.add_column(col)
        for r in doc["splits"]:
            s.add_row(
                r["split"],
                str(r["cells"]),
                str(r["pairs"]),
                f"{r['baseline'] * 100:.0f}%",
                f"{r['candidate'] * 100:.0f}%",
                f"{r['drop']:+.2f}",
                _bounds(r),
                "YES" if r["regressed"] else "",
                style="red" if r["regressed"] else None,
            )
        console.print(s)
    lk = Table(
        title=f"looks (margin {doc['margin']}, alpha {doc['alpha']}, {doc['cell_alpha']:g} of it to the cells)",
        title_justify="left",
    )
    for col in (
        "look",
        "ep/cell",
        "pairs",
        "alpha spent",
        "drop [LCB, certify UCB]",
        "IQM drop",
        "regressed",
        "decision",
    ):
        lk.add_column(col)
    for look in doc["looks"]:
        if "mean" not in look:
            lk.add_row(str(look["look"]), str(look["episodes_per_cell"]), "0", "", "n/a", "n/a", "", look["decision"])
            continue
        m, q = look["mean"], look["iqm"]
        lk.add_row(
            str(look["look"]),
            str(look["episodes_per_cell"]),
            str(look["pairs"]),
            f"{look['alpha_spent']:.4f}",
            f"{m['value']:+.3f} [{m['lcb']:+.3f}, {m['ucb']:+.3f}]",
            f"{q['value']:+.3f}" + ("" if q["used"] else " (not used)"),
            ", ".join(look["regressed"]),
            look["decision"],
        )
    console.print(lk)
    colour = {
        "regression": "bold red",
        "no_regression": "bold green",
        "inconclusive": "bold yellow",
        "nothing_measured": "bold red",
    }[doc["verdict"]]
    extra = f": {regressed_line(doc)}" if doc["regressed"] else ""
    if doc["verdict"] == "nothing_measured":
        extra = f": {doc['note']}"
    if doc["verdict"] == "inconclusive":
        extra = " — the budget could not certify either way; " + (
            "strict=true: failing" if doc["strict"] else "passing (strict=true would fail); raise episodes="
        )
    err = doc["errors"]
    if any(err.values()):
        extra += (
            f" (errored episodes, counted as failures: candidate {err['candidate']}, baseline "
            f"{err['baseline']}; {err['both']} pair(s) where both errored left out)"
        )
    console.print(f"[{colour}]{VERDICT_WORDS[doc['verdict']]}[/] (exit {doc['exit_code']}){extra}")


def write(doc: dict[str, Any], paths: dict[str, Path], console: Console) -> None:
    """Validate the verdict, then write it, its JUnit XML and its Markdown summary (each atomically), and show it."""
    doc["outputs"] = {"junit": str(paths["junit"]), "markdown": str(paths["markdown"])}
    validate(doc, "verdict")
    junit, md = junit_xml(doc), markdown(doc)
    write_atomic(paths["verdict"], doc)
    write_text_atomic(paths["junit"], junit)
    write_text_atomic(paths["markdown"], md)
    render(doc)
    console.print(
        f"verdict: {paths['verdict']} (JUnit {paths['junit'].name}, summary {paths['markdown'].name})", soft_wrap=True
    )


# -- JUnit XML ----------------------------------------------------------------------------------
def junit_xml(doc: dict[str, Any]) -> str:
    """JUnit XML of a verdict: suites `cells` (one case per cell), `aggregate` (pooled, IQM, splits), `verdict`.

    A regressed test is a <failure>; a cell whose test could not be made with the pairs it had
    (or every cell, when candidate and baseline are identical) is <skipped>; the `verdict` case
    fails exactly when the gate exits 1.
    """
    root = ET.Element("testsuites", name="bench regress")

    def suite(name: str) -> ET.Element:
        return ET.SubElement(
            root, "testsuite", name=f"bench-regress.{name}", tests="0", failures="0", skipped="0", errors="0", time="0"
        )

    def case(
        parent: ET.Element, name: str, failure: str | None = None, skipped: str | None = None, out: str | None = None
    ) -> None:
        tc = ET.SubElement(parent, "testcase", classname=parent.get("name", ""), name=name, time="0")
        parent.set("tests", str(int(parent.get("tests", "0")) + 1))
        if failure is not None:
            ET.SubElement(tc, "failure", message=failure, type="regression").text = out or failure
            out = None
            parent.set("failures", str(int(parent.get("failures", "0")) + 1))
        elif skipped is not None:
            ET.SubElement(tc, "skipped", message=skipped)
            parent.set("skipped", str(int(parent.get("skipped", "0")) + 1))
        if out:
            ET.SubElement(tc, "system-out").text = out

    cells = suite("cells")
    if doc.get("identical"):
        for name in doc.get("planned_cells", []):
            case(cells, name, skipped=doc["note"])
    for c in doc["cells"]:
        summary = (
            f"{c['pairs']} pairs: baseline {c['baseline']:.0%}, candidate {c['candidate']:.0%}, drop "
            f"{c['drop']:+.2f}, one-sided bounds {_bounds(c)}, p {c['p']}, margin {doc['margin']}"
        )
        if c["regressed"]:
            case(cells, f"{cell_name(c)} ({c['split']})", failure=f"regressed: {summary}")
        elif not c["tested"]:
            case(
                cells,
                f"{cell_name(c)} ({c['split']})",
                skipped=f"too few pairs for this cell's own test at its share of alpha ({summary})",
            )
        else:
            case(cells, f"{cell_name(c)} ({c['split']})", out=summary)
    agg = suite("aggregate")
    last = doc["looks"][-1] if doc["looks"] else {}
    for t in last.get("tests", []):
        if t["kind"] == "cell":
            continue
        summary = (
            f"drop {t['drop']:+.3f} over {t['pairs']} pairs, one-sided bounds "
            f"{_bounds(t, 'lcb', 'ucb')} at level {t.get('level')}, p {t['p']}"
        )
        if t["rejected"]:
            case(agg, t["id"], failure=f"regressed: {summary}")
        elif not t["tested"]:
            case(agg, t["id"], skipped=f"not used at this look ({summary})")
        else:
            case(agg, t["id"], out=summary)
    verdict = suite("verdict")
    headline = f"{VERDICT_WORDS[doc['verdict']]} (exit {doc['exit_code']})"
    case(verdict, "verdict", failure=headline if doc["exit_code"] != 0 else None, out=_detail(doc))
    for key in ("tests", "failures", "skipped"):
        root.set(key, str(sum(int(s.get(key, "0")) for s in root)))
    ET.indent(root)
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def _detail(doc: dict[str, Any]) -> str:
    lines = [f"verdict: {doc['verdict']} (exit {doc['exit_code']})", f"rule: {doc['rule']}"]
    if doc.get("note"):
        lines.append(f"note: {doc['note']}")
    if doc.get("regressed"):
        lines.append(f"regressed: {regressed_line(doc)}")
    for role in ("candidate", "baseline"):
        side = doc[role]
        prov = side.get("provenance") or {}
        sha = prov.get("sha256") or side.get("checkpoint_sha256")
        lines.append(f"{role}: {side['spec']} ({f'sha256 {sha}' if sha else 'no checkpoint'})")
    return "\n".join(lines)


# -- Markdown ------------------------------------------------------------------------------------
def _md(text: object) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _size(n: int | None) -> str:
    if n is None:
        return "n/a"
    size = float(n)
    for unit in ("B", "KiB", "MiB", "GiB"):
        if size < 1024 or unit == "GiB":
            return f"{size:.0f} {unit}" if unit == "B" else f"{size:.1f} {unit}"
        size /= 1024
    return str(size)


def markdown(doc: dict[str, Any]) -> str:
    """A Markdown summary of a verdict for a CI job's step summary."""
    mark = {"regression": "❌", "no_regression": "✅", "inconclusive": "⚠️", "nothing_measured": "❌"}[doc["verdict"]]
    out = [f"### {mark} Transfer gate: {VERDICT_WORDS[doc['verdict']].lower()} (exit {doc['exit_code']})", ""]
    cand, base = doc["candidate"], doc["baseline"]
    out.append(
        f"candidate `{_md(cand['spec'])}` vs baseline `{_md(base['spec'])}` · suite "
        f"{_md(doc['suite']['name'])} v{_md(doc['suite']['version'])} · metric {doc['metric']} · seed "
        f"{doc['seed']} · margin {doc['margin']} · alpha {doc['alpha']}"
    )
    out.append("")
    if doc.get("note"):
        out += [f"> {_md(doc['note'])}", ""]
    if doc.get("regressed"):
        out.append("**Regressed:**")
        out += [
            f"- {r['kind']} **{_md(r['name'])}**: drop {r['drop']:+.2f}, one-sided bounds "
            f"[{r['lcb']:+.2f}, {r['ucb']:+.2f}] (level {r['level']:.4f}) > margin {doc['margin']}"
            for r in doc["regressed"]
        ]
        out.append("")
    if doc["looks"] and "mean" in doc["looks"][-1]:
        last = doc["looks"][-1]
        m = last["mean"]
        out.append(
            f"Pooled drop {m['value']:+.3f} (lower bound {m['lcb']:+.3f}, certifying upper bound "
            f"{m['ucb']:+.3f}) over {last['pairs']} {'episodes' if doc.get('pairing') == 'unpaired' else 'pairs'}; look {last['look']} of {len(doc['schedule'])} "
            f"({last['episodes_per_cell']} episodes per cell)"
            + (", stopped early" if doc["stopped_early"] else "")
            + "."
        )
        out.append("")
    if doc["cells"]:
        out += [
            "| cell | split | pairs | baseline | candidate | drop | bounds | p | |",
            "|---|---|--:|--:|--:|--:|--:|--:|---|",
        ]
        for c in doc["cells"]:
            flag = "**regressed**" if c["regressed"] else ("" if c["tested"] else "not tested")
            out.append(
                f"| {_md(cell_name(c))} | {c['split']} | {c['pairs']} | {c['baseline']:.0%} | "
                f"{c['candidate']:.0%} | {c['drop']:+.2f} | {_bounds(c)} | "
                f"{'n/a' if c['p'] is None else format(c['p'], '.2g')} | {flag} |"
            )
        out.append("")
    out += ["| | checkpoint | sha256 | size | training metadata |", "|---|---|---|--:|---|"]
    for role in ("candidate", "baseline"):
        side = doc[role]
        prov = side.get("provenance") or {}
        sha = prov.get("sha256") or side.get("checkpoint_sha256")
        training = prov.get("training")
        meta = _md(json.dumps(training, sort_keys=True))[:300] if training else "none stored"
        out.append(
            f"| {role} | `{_md(prov.get('path') or side.get('checkpoint') or side['spec'])}` | "
            f"{'`' + sha[:16] + '`' if sha else 'n/a'} | {_size(prov.get('size_bytes'))} | {meta} |"
        )
    out += ["", f"<details><summary>rule</summary>\n\n{_md(doc['rule'])}\n\n</details>", ""]
    return "\n".join(out)
