"""The committed result tables are what their JSON renders to: table.md (what the docs quote)
and table.json (what the checks and the board read) cannot drift apart."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchmark.reproduction.report import render_markdown

RESULTS = Path(__file__).resolve().parents[1] / "docs" / "results"
TABLES = sorted(p.parent.name for p in RESULTS.glob("*/table.json"))


def test_there_are_committed_tables():
    assert len(TABLES) >= 4, TABLES


@pytest.mark.parametrize("name", TABLES)
def test_table_md_is_its_json_rendered(name):
    table = json.loads((RESULTS / name / "table.json").read_text())
    assert render_markdown(table) == (RESULTS / name / "table.md").read_text()
