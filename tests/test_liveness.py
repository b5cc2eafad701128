"""Batch jobs end, and say so in one line: a cluster without workers (from the start, or
after losing them all) fails within ``cluster.NO_WORKER_TIMEOUT_S``, and Ctrl-C prints only
``<tool>: interrupted`` (docs/CLI.md).

The clusters are real: a ``distributed`` scheduler on 127.0.0.1 in this process, workers as
``dask worker`` processes; the CLIs run as subprocesses. The no-worker timeout is shortened
through ``cluster.NO_WORKER_ENV``.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from distributed import Client, LocalCluster, as_completed

from basic_shapes import cluster
from test_label import LBAND, write_dataset

ROOT = Path(__file__).resolve().parents[1]
TIMEOUT_S = 3  # the shortened no-worker timeout


@pytest.fixture
def scheduler():
    """The address of a real scheduler on 127.0.0.1 that has no workers."""
    with LocalCluster(n_workers=0, host="127.0.0.1", dashboard_address=None) as c:
        yield c.scheduler_address


def snapshot(directory: Path) -> dict:
    return {str(p): p.stat().st_mtime_ns for p in sorted(directory.rglob("*"))}


def run(*args, env=None) -> tuple[subprocess.CompletedProcess, float]:
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", *map(str, args)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
        env={**os.environ, cluster.NO_WORKER_ENV: str(TIMEOUT_S), **(env or {})},
    )
    return proc, time.perf_counter() - t0


def test_jobs_on_a_cluster_without_workers_fail_in_one_line(scheduler, tmp_path):
    data = write_dataset(tmp_path / "data", n_objects=2, objects_per_shard=2)
    config = tmp_path / "lband.json"
    config.write_text(json.dumps(LBAND))
    before = snapshot(data)
    for args, where in [
        (
            [
                "radar_sim.cli",
                "label",
                "--data",
                data,
                "--config",
                config,
                "--quiet",
                "--scheduler",
                scheduler,
            ],
            "radar-sim label",
        ),
        (
            [
                "basic_shapes.cli",
                "generate",
                "--data",
                tmp_path / "g",
                "--classes",
                "cube",
                "--objects-per-class",
                "1",
                "--variants",
                "0",
                "--quiet",
                "--scheduler",
                scheduler,
            ],
            "basic-shapes generate",
        ),
    ]:
        proc, wall = run(*args)
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode == 1 and len(lines) == 1, proc.stderr
        assert lines[0].startswith(
            f"{where}: error: --scheduler {scheduler}: no Dask worker for {TIMEOUT_S} s"
        ), lines[0]
        assert "rerun" in lines[0]
        assert TIMEOUT_S <= wall < TIMEOUT_S + 30
    assert snapshot(data) == before  # nothing half-written: a rerun starts where it stopped
    assert sorted(p.name for p in (tmp_path / "g").iterdir()) == ["dataset.json"]


def test_losing_every_worker_fails_within_the_timeout(scheduler, monkeypatch):
    monkeypatch.setenv(cluster.NO_WORKER_ENV, str(TIMEOUT_S))
    worker = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "distributed.cli.dask_worker",
            scheduler,
            "--no-nanny",
            "--nthreads",
            "1",
            "--host",
            "127.0.0.1",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        with Client(scheduler) as client:
            client.wait_for_workers(1, timeout=60)
            futures = as_completed([client.submit(time.sleep, 600, pure=False)])
            deadline = time.monotonic() + 30
            while not client.processing()[next(iter(client.nthreads()))]:
                assert time.monotonic() < deadline, "the task never started"
                time.sleep(0.05)
            worker.kill()
            t0 = time.perf_counter()
            with pytest.raises(cluster.NoWorkersError, match=f"no Dask worker for {TIMEOUT_S} s"):
                list(cluster.finished(client, futures))
            assert time.perf_counter() - t0 < TIMEOUT_S + 10
    finally:
        worker.kill()
        worker.wait()


def test_ctrl_c_during_label_prints_one_line(tmp_path):
    """SIGINT to the whole process group, as a terminal sends it, while the Dask workers run."""
    data = write_dataset(tmp_path / "data", n_objects=12, objects_per_shard=12)
    sidecar = data / ".labels" / "shard-00000"  # the default config: large objects take seconds
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "radar_sim.cli",
            "label",
            "--data",
            data,
            "--workers",
            "1",
            "--quiet",
        ],
        cwd=ROOT,
        start_new_session=True,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.time() + 120
    while proc.poll() is None and not any(sidecar.glob("object-*.h5")):
        assert time.time() < deadline, "no object finished"
        time.sleep(0.01)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    lines = err.strip().splitlines()
    assert proc.returncode == 130 and "Traceback" not in err, err
    assert lines == ["radar-sim: interrupted"], err
    assert 1 <= len(list(sidecar.glob("object-*.h5"))) < 12  # finished objects are kept
    shutil.rmtree(data)
