import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"


@pytest.fixture
def shared_dir() -> Path:
    """../shared beside the checkout (measured logs, reference files); skip when absent."""
    if not SHARED.is_dir():
        pytest.skip(f"../shared not found at {SHARED}: reference data is only available beside the checkout")
    return SHARED


@pytest.fixture(scope="session")
def lerobot_python() -> str:
    """The python of lerobot's side venv (BENCH_LEROBOT_PYTHON); skip when unset (tests/lerobot_side.py)."""
    py = os.environ.get("BENCH_LEROBOT_PYTHON", "")
    if not py:
        pytest.skip(
            "BENCH_LEROBOT_PYTHON is not set: lerobot lives in a side venv (it brings pandas and a CUDA "
            "torch); build it with `bash .ci/lerobot-venv.sh` and set BENCH_LEROBOT_PYTHON=.lerobot-venv/bin/python"
        )
    if not Path(py).exists():
        pytest.fail(f"BENCH_LEROBOT_PYTHON={py} does not exist")
    return py


@pytest.fixture(autouse=True)
def _quiet_env(monkeypatch):
    monkeypatch.setenv("MUJOCO_GL", os.environ.get("MUJOCO_GL", "disable"))


@pytest.fixture
def vulkan_icd() -> str:
    """The Vulkan driver manifest (VK_ICD_FILENAMES) for tests marked `vulkan`; skip when none is set up."""
    icd = os.environ.get("VK_ICD_FILENAMES", "")
    if not icd or not all(Path(p).is_file() for p in icd.split(os.pathsep)):
        pytest.skip(
            "no Vulkan device set up: run scripts/fetch_lavapipe.sh and export the VK_ICD_FILENAMES it "
            "prints (then pytest -m vulkan)"
        )
    return icd


try:  # property tests: deterministic in CI (fixed seeds from the test's name), no example database on disk
    from hypothesis import settings as _hyp_settings

    _hyp_settings.register_profile("bench", database=None, derandomize=True, deadline=None)
    _hyp_settings.load_profile("bench")
except ImportError:  # hypothesis is in the test extra; without it the property tests are skipped
    pass
