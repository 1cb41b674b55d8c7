"""The architecture the code enforces (docs/architecture.md): the layer contract and the deferred-import rule.

The contract itself is written once, in pyproject.toml's `[tool.importlinter]`, and checked by
import-linter (`lint-imports`, also run by `.ci/run`); this test runs the same check so that a plain
`pytest` catches a broken layer too.
"""

from __future__ import annotations

import ast
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _lint_imports() -> str:
    exe = shutil.which("lint-imports") or str(Path(sys.executable).with_name("lint-imports"))
    if not Path(exe).exists():
        pytest.skip("import-linter is not installed (pip install -e '.[test]')")
    return exe


def test_layer_contract_is_kept():
    r = subprocess.run([_lint_imports(), "--no-cache"], cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-2000:]
    assert "4 kept, 0 broken" in r.stdout


def test_the_contract_names_every_layer_package():
    """Each subpackage of bench has a one-line purpose and a place in the layers (exhaustive=true)."""
    import tomllib

    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    layers = next(c for c in cfg["contracts"] if c["id"] == "layers")
    assert layers["exhaustive"] is True and layers["containers"] == ["bench"]
    named = {n.strip() for layer in layers["layers"] for n in layer.replace(":", "|").split("|")}
    packages = {p.name for p in (ROOT / "bench").iterdir() if (p / "__init__.py").exists()}
    assert packages <= named, sorted(packages - named)
    for name in packages:
        doc = ast.get_docstring(ast.parse((ROOT / "bench" / name / "__init__.py").read_text()))
        assert doc and doc.strip(), f"bench/{name}/__init__.py has no one-line purpose"


def _deferred_imports(path: Path) -> list[tuple[int, str]]:
    """(line, source) of every import statement inside a function of `path`."""
    src = path.read_text()
    lines = src.splitlines()
    out = []
    for fn in ast.walk(ast.parse(src)):
        if isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
            for node in ast.walk(fn):
                if isinstance(node, (ast.Import, ast.ImportFrom)):
                    out.append((node.lineno, "\n".join(lines[node.lineno - 1 : node.end_lineno])))
    return sorted(set(out))


def test_every_deferred_import_says_why():
    """An import inside a function keeps a heavy module out of start-up, and its line says which and why."""
    silent = [
        f"{p.relative_to(ROOT)}:{line}: {stmt.strip()}"
        for p in sorted((ROOT / "bench").rglob("*.py"))
        for line, stmt in _deferred_imports(p)
        if "#" not in stmt
    ]
    assert not silent, "deferred imports without a reason:\n" + "\n".join(silent)


def test_the_deferred_import_check_sees_a_silent_one(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("def f():\n    import json\n\n    return json\n\n\ndef g():\n    import mujoco  # heavy\n")
    found = _deferred_imports(f)
    assert [(line, "#" in s) for line, s in found] == [(2, False), (8, True)]
