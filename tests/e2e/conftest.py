"""Where the browser test saves its screenshots."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPOSITORY = Path(__file__).resolve().parents[2]
SCREENSHOTS_ENV = "CROWDTELEOP_SCREENSHOTS"


@pytest.fixture
def screenshots(tmp_path: Path) -> Path:
    """A temporary folder; or the folder ``$CROWDTELEOP_SCREENSHOTS`` names (relative to the
    repository), as `make screenshots` does to refresh the README's pictures in
    docs/screenshots/. A test run never writes into tracked files otherwise."""
    chosen = os.environ.get(SCREENSHOTS_ENV)
    directory = REPOSITORY / chosen if chosen else tmp_path / "screenshots"
    directory.mkdir(parents=True, exist_ok=True)
    return directory
