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


@pytest.fixture(autouse=True)
def _quiet_env(monkeypatch):
    monkeypatch.setenv("MUJOCO_GL", os.environ.get("MUJOCO_GL", "disable"))
