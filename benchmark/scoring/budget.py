"""The labels' own physics error per class (``physics_budget.json``, made by
perf/budget_summary.py from the exact references): what a score is to be read against."""

from __future__ import annotations

import functools
from pathlib import Path

from basic_shapes.infra import load_json

PATH = Path(__file__).with_name("physics_budget.json")


@functools.cache
def load() -> dict:
    return load_json(PATH, max_bytes=1 << 16, max_depth=6, what=f"{PATH}: physics budget")


def rows(physics: str, classes: list[str]) -> list[dict]:
    """``[{"class", "reference", "all_bins_db2": [lo, hi], "near_peak_db2": [lo, hi]}]`` for the
    classes the budget covers under radar config ``physics`` ("xband-v1", ...)."""
    known = load()["physics"].get(physics, {})
    return [{"class": c, **known[c]} for c in classes if c in known]
