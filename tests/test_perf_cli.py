"""`bench perf`: its measurements as JSON (`out=`), whatever the temporary folder already holds."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TOY = "suite=tests.toy_suite:ToySuite"


def perf(tmp: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(REPO), "TMPDIR": str(tmp)}
    return subprocess.run(
        [sys.executable, "-m", "bench", "perf", TOY, "episodes=2", *args],
        cwd=tmp,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_perf_writes_json_beside_a_perf_folder_in_the_temporary_directory(tmp_path):
    (tmp_path / "perf").mkdir()  # a folder named like the old fixed run directory: untouched
    (tmp_path / "perf" / "notes.txt").write_text("mine")
    res = perf(tmp_path, "scaling_episodes=4", "workers=2", "out=m.json")
    assert res.returncode == 0, res.stderr[-2000:]
    doc = json.loads((tmp_path / "m.json").read_text())
    assert doc["schema"] == "bench.perf/1" and doc["suite"] == "toy" and doc["cell"] == "reach/a/line"
    assert doc["harness_vs_bare"]["steps"] == 60 and doc["harness_vs_bare"]["ratio"] > 0
    assert doc["scaling"]["workers"] == 2 and doc["scaling"]["ratio_steady"] > 0
    assert (tmp_path / "perf" / "notes.txt").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.json", "perf"]  # its scratch folders are gone
    again = perf(tmp_path, "scaling_episodes=0", "out=m.json")  # never overwritten
    lines = again.stderr.strip().splitlines()
    assert again.returncode == 2 and len(lines) == 1 and lines[0].startswith("error: out=") and "exists" in lines[0]
    bad = perf(tmp_path, "scaling_episodes=0", "out=m.txt")
    assert bad.returncode == 2 and "ending in .json" in bad.stderr
