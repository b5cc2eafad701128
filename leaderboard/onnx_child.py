"""The child process in which `leaderboard evaluate-model` runs a submitted ONNX model.

Run as ``python -m leaderboard.onnx_child MODEL DATA PREDICTIONS REPORT MEMORY_MB CPU_S``.
Before anything else it lowers its own limits (``resource.setrlimit``: address space
``MEMORY_MB`` MiB, CPU time ``CPU_S`` s, no core files) and, where the kernel lets it, moves
into a network namespace of its own (nothing to connect to; a model needs no network, and
onnxruntime opens none). Then it opens the model with onnxruntime (one intra-op and one
inter-op thread, sequential execution, no spinning), runs it once on the first test mesh
(warm-up, not counted), then mesh by mesh over every scored test mesh (``scored_mesh_rows``: the
OOD meshes included), timing the board-computed inputs the model declares and the run, and
writes the predictions file and a JSON report. The parent enforces the wall-time limit (it
kills the whole process group). Any failure is one line on stderr and exit status 1.
"""

from __future__ import annotations

import ctypes
import json
import os
import resource
import sys
import time

CLONE_NEWUSER, CLONE_NEWNET = 0x10000000, 0x40000000


def limit(memory_mb: int, cpu_s: int) -> None:
    mem = int(memory_mb) << 20
    resource.setrlimit(resource.RLIMIT_AS, (mem, mem))
    resource.setrlimit(resource.RLIMIT_CPU, (int(cpu_s), int(cpu_s) + 5))
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))


def isolate_network() -> bool:
    """Enter a new network namespace (loopback only, down); False where not permitted."""
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        unshare = libc.unshare
    except (OSError, AttributeError):
        return False
    if unshare(CLONE_NEWNET) == 0:
        return True
    return unshare(CLONE_NEWUSER | CLONE_NEWNET) == 0


def run(model_path: str, data_dir: str, predictions: str, report: str) -> dict:
    import numpy as np
    import onnxruntime

    from basic_shapes.infra import hardware
    from benchmark.scoring.data import BenchmarkData
    from benchmark.scoring.onnx_model import (
        check_output,
        inspect,
        mesh_inputs,
        read_model_bytes,
        session,
    )
    from benchmark.scoring.protocol import PredictionsWriter, scored_mesh_rows

    raw = read_model_bytes(model_path)
    info = inspect(model_path, raw)
    sess = session(raw, threads=1)
    with BenchmarkData(data_dir) as data:
        rows = scored_mesh_rows(data)
        shape = data.target_shape

        def feeds(row: int) -> dict:
            b = data.batch(np.array([row]))
            return mesh_inputs(
                info.inputs, b["vertices"][0], b["faces"][0], b["scale_m"][0], b["scale_bins"][0]
            )

        t0 = time.perf_counter()
        check_output(sess.run(None, feeds(int(rows[0])))[0], shape, "warm-up")
        warmup = time.perf_counter() - t0
        inputs_s = run_s = 0.0
        with PredictionsWriter(
            predictions,
            data.fingerprint,
            len(rows),
            shape,
            label_fingerprint=data.label_fingerprint,
        ) as out:
            for row in rows:
                uid = int(data.meshes["uid"][row])
                b = data.batch(np.array([row]))
                t0 = time.perf_counter()
                f = mesh_inputs(
                    info.inputs,
                    b["vertices"][0],
                    b["faces"][0],
                    b["scale_m"][0],
                    b["scale_bins"][0],
                )
                t1 = time.perf_counter()
                (pred,) = sess.run(None, f)
                t2 = time.perf_counter()
                inputs_s, run_s = inputs_s + t1 - t0, run_s + t2 - t1
                out.write(np.array([uid]), check_output(pred, shape, f"mesh_uid {uid}")[None])
    n = len(rows)
    result = {
        "n_meshes": n,
        "ms_per_mesh": 1000.0 * (inputs_s + run_s) / n,
        "run_ms_per_mesh": 1000.0 * run_s / n,
        "inputs_ms_per_mesh": 1000.0 * inputs_s / n,
        "warmup_ms": 1000.0 * warmup,
        "onnxruntime": onnxruntime.__version__,
        "hardware": hardware(1),
        "peak_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
    }
    with open(report, "w") as fh:
        json.dump(result, fh)
    return result


def main(argv: list[str]) -> int:
    model_path, data_dir, predictions, report, memory_mb, cpu_s = argv
    limit(int(memory_mb), int(cpu_s))
    isolated = isolate_network()
    try:
        result = run(model_path, data_dir, predictions, report)
    except MemoryError:
        print(f"ran out of the memory limit of {memory_mb} MiB", file=sys.stderr)
        return 1
    except Exception as exc:
        from basic_shapes.infra import one_line

        text = one_line(exc)
        if "bad_alloc" in text or "Failed to allocate" in text:
            text = f"ran out of the memory limit of {memory_mb} MiB ({text[:120]})"
        print(text, file=sys.stderr)
        return 1
    result["network_isolated"] = isolated
    with open(report, "w") as fh:
        json.dump(result, fh)
    return 0


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    sys.exit(main(sys.argv[1:]))
