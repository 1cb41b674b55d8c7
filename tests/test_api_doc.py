"""docs/api.md: the example there, extracted verbatim, runs on real robosuite."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def test_the_api_example_runs(tmp_path: Path):
    pytest.importorskip("robosuite")
    text = (REPO / "docs" / "api.md").read_text()
    code = re.search(r"```python\n(# api_example.py.*?)```", text, re.S).group(1)
    (tmp_path / "api_example.py").write_text(code)
    res = subprocess.run([sys.executable, "api_example.py"], cwd=tmp_path, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-3000:]
    assert "4 episodes on ['Lift/Panda/default', 'Lift/UR5e/default'] horizon 60" in res.stdout
    assert "episodes run now: 4 already recorded: 0" in res.stdout
    assert (tmp_path / "runs" / "api-example" / "summary.json").is_file()
