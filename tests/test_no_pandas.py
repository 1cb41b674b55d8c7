"""No pandas anywhere in the core dependency tree (lerobot brings it; it lives only in a side venv, see README)."""

import re
from importlib.metadata import PackageNotFoundError, distribution


def _requirements(dist_name: str) -> list[str]:
    try:
        reqs = distribution(dist_name).requires or []
    except PackageNotFoundError:
        return []
    out = []
    for req in reqs:
        if "extra ==" in req:  # optional extras are not part of the core tree
            continue
        out.append(re.split(r"[ ;<>=!~\[(]", req, maxsplit=1)[0].lower().replace("_", "-"))
    return out


def test_pandas_not_in_resolved_core_tree():
    seen, stack, parents = set(), ["bench-harness"], {}
    while stack:
        name = stack.pop()
        if name in seen:
            continue
        seen.add(name)
        for dep in _requirements(name):
            parents.setdefault(dep, name)
            stack.append(dep)
    assert "bench-harness" in seen and len(seen) > 10, "the installed dependency tree could not be walked"
    assert "pandas" not in seen, f"pandas is pulled in by {parents.get('pandas')}"
