"""Every ```python example in README.md and docs/*.md runs as written.

The examples run in a scratch directory where ``out/demo/data`` and ``data/bs`` are a real
labelled dataset (tiny-v1, built once with the toolkit: every class, OOD meshes, labels) and
``out/*.nc`` its g2s export. Names an example leaves to the reader are the only thing given:
``my_model`` / ``my_network`` (a flat -40 dB prediction), a mesh (``vertices``, ``faces``: a
0.3 m cube), ``frequencies_hz`` / ``freq_hz``, ``directions`` and ``aspect_deg``. A block whose
first line is ``# name.py`` is a file: it is written and imported. Blocks fenced as ```text
(API summaries) are not examples.
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
BLOCK = re.compile(r"^```python\n(.*?)^```", re.S | re.M)


def examples() -> list:
    out = []
    for doc in DOCS:
        text = doc.read_text()
        for i, m in enumerate(BLOCK.finditer(text)):
            line = text[: m.start()].count("\n") + 1
            out.append(pytest.param(m.group(1), id=f"{doc.name}:{line}:{i}"))
    return out


@pytest.fixture(scope="module")
def scratch(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("docs")
    data = root / "tiny-v1"
    for cmd in (
        ["benchmark.cli", "dataset", "tiny-v1", "--data", str(data), "--workers", "0", "--quiet"],
        [
            "basic_shapes.cli",
            "export",
            "--data",
            str(data),
            "--format",
            "g2s",
            "--out",
            str(root / "out"),
        ],
    ):
        proc = subprocess.run([sys.executable, "-m", *cmd], capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr
    (root / "out" / "demo").mkdir()
    (root / "out" / "demo" / "data").symlink_to(data)
    (root / "data").mkdir()
    (root / "data" / "bs").symlink_to(data)
    return root


def placeholders(target_shape) -> dict:
    import torch
    import trimesh

    cube = trimesh.creation.box(extents=(0.3, 0.3, 0.3))

    def my_model(item):
        return torch.full(tuple(item["target"].shape), -40.0)

    def my_network(batch):
        return np.full((len(batch["scale_m"]), *target_shape), -40.0, np.float32)

    return {
        "my_model": my_model,
        "my_network": my_network,
        "vertices": np.asarray(cube.vertices, np.float32),
        "faces": np.asarray(cube.faces, np.int32),
        "frequencies_hz": np.linspace(8e9, 12e9, 16),
        "freq_hz": np.linspace(8e9, 12e9, 16),
        "directions": np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]),
        "aspect_deg": np.array([0.0, 45.0, 90.0]),
    }


def test_every_doc_has_its_examples_collected():
    assert len(examples()) >= 10


@pytest.mark.parametrize("code", examples())
def test_example_runs_as_written(code, scratch, monkeypatch):
    from benchmark.scoring.data import BenchmarkData

    monkeypatch.chdir(scratch)
    first = code.splitlines()[0].strip()
    if re.fullmatch(r"# [\w]+\.py", first):
        path = scratch / first[2:]
        path.write_text(code)
        spec = importlib.util.spec_from_file_location(path.stem, path)
        spec.loader.exec_module(importlib.util.module_from_spec(spec))
        return
    with BenchmarkData(scratch / "out" / "demo" / "data") as data:
        shape = data.target_shape
    namespace = {"__name__": "__doc_example__", **placeholders(shape)}
    exec(compile(code, "<doc example>", "exec"), namespace)  # our own docs, as written
    assert os.getcwd() == str(scratch)
