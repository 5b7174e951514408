"""The browser pages (plain ES modules, no build step) the coordination server serves."""

from pathlib import Path

STATIC_DIR = Path(__file__).parent / "static"
