"""docs/architecture.md says what tests/test_architecture.py enforces: each row of its two
"may import" tables is the rule table's entry for that package, no more and no less."""

from __future__ import annotations

import re
from pathlib import Path

from tests.test_architecture import COORD_MAY_IMPORT, MAY_IMPORT

DOC = Path(__file__).resolve().parents[1] / "docs" / "architecture.md"
NOTHING = "nothing of ours", "nothing of coord"


def _tables(text: str) -> list[dict[str, set[str]]]:
    """Every markdown table whose last column is "may import": package -> the names it lists."""
    tables: list[dict[str, set[str]]] = []
    rows: dict[str, set[str]] | None = None
    for line in text.splitlines():
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if not line.startswith("|"):
            rows = None
        elif cells[-1] == "may import":
            rows = {}
            tables.append(rows)
        elif rows is not None and not set(cells[0]) <= set("-: "):
            allowed = set() if cells[-1] in NOTHING else set(re.findall(r"`([^`]+)`", cells[-1]))
            for name in re.findall(r"`([^`]+)`", cells[0]):
                rows[name] = allowed
    return tables


def _differences(doc: dict[str, set[str]], rules: dict[str, set[str]]) -> list[str]:
    found = [f"{name}: not in the doc" for name in sorted(set(rules) - set(doc))]
    found += [f"{name}: not in the rules" for name in sorted(set(doc) - set(rules))]
    for name in sorted(set(doc) & set(rules)):
        if doc[name] != rules[name]:
            found.append(f"{name}: doc {sorted(doc[name])}, rules {sorted(rules[name])}")
    return found


def _package_tables() -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    packages, coord = _tables(DOC.read_text())
    coord = {name.removeprefix("coord."): allowed for name, allowed in coord.items()}
    return packages, coord


def _documented_rules() -> dict[str, set[str]]:
    """The packages a reader can see: the entry points `__main__`/`__init__` are not listed."""
    return {name: allowed for name, allowed in MAY_IMPORT.items() if not name.startswith("__")}


def test_the_package_table_is_the_rule_table():
    packages, _ = _package_tables()
    assert not (found := _differences(packages, _documented_rules())), "\n".join(found)


def test_the_coordinator_table_is_its_rule_table():
    _, coord = _package_tables()
    rules = {name: allowed for name, allowed in COORD_MAY_IMPORT.items() if name != "__init__"}
    assert not (found := _differences(coord, rules)), "\n".join(found)


def test_a_row_that_drifts_from_the_rules_is_caught():
    packages, _ = _package_tables()
    assert _differences({**packages, "sim": packages["sim"] | {"teleop"}}, _documented_rules())
    missing = {name: allowed for name, allowed in packages.items() if name != "learn"}
    assert _differences(missing, _documented_rules()) == ["learn: not in the doc"]
