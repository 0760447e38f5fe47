"""Documentation/safety.md's hazard table names, for every hazard, the tests that prove its check: every named test
must exist in the suite, and every hazard must name at least one (issue 23)."""

import ast
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TABLE = ROOT / "Documentation" / "safety.md"
TEST_NAME = re.compile(r"`(Testing/[\w/]+\.py)::(test_\w+)`")


def hazard_rows():
    """{hazard id: its row's cells} of the table (rows starting '| H<n> |')."""
    rows = {}
    for line in TABLE.read_text(encoding="utf-8").splitlines():
        cells = [cell.strip() for cell in line.strip().strip("|").split("|")]
        if re.fullmatch(r"H\d+", cells[0]):
            rows[cells[0]] = cells
    return rows


def defined_tests(path):
    tree = ast.parse((ROOT / path).read_text(encoding="utf-8"))
    return {node.name for node in ast.walk(tree) if isinstance(node, ast.FunctionDef) and node.name.startswith("test_")}


def test_every_hazard_names_a_test_and_every_named_test_exists():
    rows = hazard_rows()
    assert len(rows) >= 15 and list(rows) == [f"H{number}" for number in range(1, len(rows) + 1)]
    missing = []
    for hazard, cells in rows.items():
        assert len(cells) == 6, f"{hazard}: expected 6 columns, got {len(cells)}"
        named = TEST_NAME.findall(cells[-1])
        assert named, f"{hazard} names no test"
        missing += [f"{hazard}: {path}::{name}" for path, name in named if name not in defined_tests(path)]
    assert not missing, f"tests named in {TABLE.name} that do not exist: {missing}"


def test_the_hazards_of_issue_23_are_all_in_the_table():
    text = " ".join(cells[1].lower() for cells in hazard_rows().values())
    for hazard in (
        "marker pairing",
        "units",
        "lps read as ras",
        "tracker coordinates",
        "degenerate or duplicated",
        "threshold outside bone",
        "touches far from the bone",
        "coarse fit beyond the marker error",
        "fine step that moves the targets",
        "stale or invalid tracking",
        "uncalibrated",
        "tilted",
    ):
        assert hazard in text, f"no hazard row mentions {hazard!r}"
