"""Fixtures the dataset tests share."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def lerobot_python() -> str:
    """The python of LeRobot's virtualenv; made once (cached), and a failure to make it fails
    the test with pip's output: it must not skip in CI."""
    command = [str(ROOT / "scripts" / "lerobot-venv.sh"), sys.executable]
    try:
        made = subprocess.run(command, capture_output=True, text=True, timeout=3600)
    except subprocess.TimeoutExpired as exc:
        pytest.fail(f"scripts/lerobot-venv.sh timed out:\n{exc.stdout}\n{exc.stderr}")
    print(made.stdout, made.stderr)  # in the pytest log of a failing test
    if made.returncode != 0:
        pytest.fail(f"scripts/lerobot-venv.sh failed:\n{made.stdout}\n{made.stderr}")
    return made.stdout.strip().splitlines()[-1]
