"""The written CLI convention (docs/CLI.md) on the four real tools' parsers."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from basic_shapes import __version__, infra

TOOLS = {
    "basic-shapes": "basic_shapes.cli",
    "radar-sim": "radar_sim.cli",
    "benchmark": "benchmark.cli",
    "leaderboard": "leaderboard.cli",
}


@pytest.mark.parametrize("tool", TOOLS)
def test_every_tool_prints_the_toolkit_version(tool):
    proc = subprocess.run(
        [sys.executable, "-m", TOOLS[tool], "--version"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0 and proc.stdout.strip() == f"{tool} {__version__}"


def _raising(exc):
    def body(argv):
        raise exc

    return body


@pytest.mark.parametrize(
    "raised, shown",
    [
        (SystemExit("tool run: oops"), "tool run: error: oops"),
        (SystemExit("tool: error: oops"), "tool run: error: oops"),
        (SystemExit("data/x.h5: broken"), "tool run: error: data/x.h5: broken"),
        (ValueError("--data d: empty"), "tool run: error: --data d: empty"),
    ],
)
def test_errors_carry_tool_and_command_once(raised, shown):
    with pytest.raises(SystemExit) as info:
        infra.cli_boundary("tool", _raising(raised), ["run", "--flag"])
    assert info.value.code == shown


def test_generate_without_sizes_starts_nothing(tmp_path):
    """300,000 meshes by default was the trap: the sizes are required (exit 2, nothing made)."""
    from basic_shapes.cli import main

    with pytest.raises(SystemExit) as info:
        main(["generate", "--data", str(tmp_path / "d")])
    assert info.value.code == 2 and not (tmp_path / "d").exists()


def test_workers_and_scheduler_exclude_each_other(tmp_path, capsys):
    from radar_sim.cli import main

    with pytest.raises(SystemExit) as info:
        main(["label", "--data", str(tmp_path), "--workers", "1", "--scheduler", "tcp://h:1"])
    assert info.value.code == 2 and "not allowed with" in capsys.readouterr().err


def test_in_process_dask_worker_runs_tasks():
    """``--workers 0`` for Dask-backed commands: one worker thread, in this very process."""
    from basic_shapes.cluster import dask_client

    with dask_client(workers=0) as client:
        assert len(client.nthreads()) == 1
        assert client.submit(os.getpid, pure=False).result() == os.getpid()
