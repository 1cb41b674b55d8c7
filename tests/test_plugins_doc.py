"""docs/plugins.md: the suite shown there, extracted verbatim, runs through `bench check` and `bench run`."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def _doc_code() -> str:
    text = (REPO / "docs" / "plugins.md").read_text()
    block = re.search(r"## A new suite in about 60 lines.*?```python\n(.*?)```", text, re.S)
    assert block, "docs/plugins.md lost its example"
    return block.group(1)


def _bench(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "bench", *args], cwd=tmp_path, capture_output=True, text=True, timeout=300
    )


def test_the_documented_suite_is_about_60_lines_and_runs(tmp_path: Path):
    code = _doc_code()
    lines = [ln for ln in code.splitlines() if ln.strip() and not ln.strip().startswith("#")]
    assert len(lines) <= 90, len(lines)  # "about 60 lines" of code, the policy factory included
    (tmp_path / "my_suite.py").write_text(code)
    res = _bench(tmp_path, "check", "suite=my_suite:PointSuite")
    assert res.returncode == 0 and "clean" in res.stdout, res.stdout + res.stderr
    res = _bench(tmp_path, "run", "suite=my_suite:PointSuite", "policy=scripted", "episodes=20", "run_id=a")
    assert res.returncode == 0, res.stderr[-2000:]
    summary = json.loads((tmp_path / "runs" / "a" / "summary.json").read_text())
    assert summary["suite"]["radius"] == 0.05 and summary["counts"]["episodes"] == 60
    seen = summary["splits"]["seen"]["success_once"]["mean"]["value"]
    unseen = summary["splits"]["unseen"]["success_once"]["mean"]["value"]
    assert seen > unseen  # the controller tuned for light masses transfers worse to the heavy one
    res = _bench(
        tmp_path, "run", "suite=my_suite:PointSuite", "policy=my_suite:push", "radius=0.1", "episodes=2", "run_id=b"
    )
    assert res.returncode == 0, res.stderr[-2000:]
    res = _bench(tmp_path, "run", "suite=my_suite:PointSuite", "radiu=0.1", "run_id=c")
    assert res.returncode == 2 and "Did you mean 'radius'" in res.stderr
