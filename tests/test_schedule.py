"""`make test`'s two workers: the modules that share Ray are one unit, handed out first, and
slow modules before quick ones (tests/fixtures/schedule.py)."""

from __future__ import annotations

from pathlib import Path

from tests.fixtures.schedule import rank_of, scope_of

ROOT = Path(__file__).parent.parent
RAY_MODULES = [
    "tests/coord/test_deploy_guide.py",
    "tests/coord/test_ray_launcher.py",
    "tests/coord/test_ray_replicas.py",
    "tests/learn/test_ray_vec.py",
]


def test_the_modules_that_share_ray_are_one_unit() -> None:
    assert {scope_of(ROOT, f"{module}::test_x") for module in RAY_MODULES} == {"serial:ray"}
    assert scope_of(ROOT, "tests/test_docs.py::test_x[a::b]") == "tests/test_docs.py"


def test_the_ray_unit_goes_first_then_slow_modules_then_quick_ones() -> None:
    units = ["tests/test_docs.py", "tests/e2e/test_web_e2e.py", "serial:ray"]
    assert sorted(units, key=lambda unit: rank_of(ROOT, unit)) == units[::-1]
