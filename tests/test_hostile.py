"""Hostile inputs (issue 12): every case is refused in one line, writes nothing, and stays
within a memory and time bound.

Each CLI case runs in a subprocess under ``RLIMIT_AS`` (``MEMORY_LIMIT``) and a timeout; the
test asserts the exit status, exactly one stderr line holding the expected phrase, no
traceback, and no file created, changed or removed in the case's directories. Hostile files
are built with h5py directly. Set ``HOSTILE_REPORT=path.json`` to record each case's peak
memory (max RSS) and wall time.
"""

from __future__ import annotations

import ctypes
import http.server
import json
import os
import re
import resource
import shutil
import socketserver
import subprocess
import sys
import threading
import time
import types
from pathlib import Path

import h5py
import numpy as np
import pytest

from basic_shapes import infra
from basic_shapes.shards import (
    MeshRecord,
    ObjectRecord,
    Shard,
    ShardError,
    content_fingerprint,
    iter_objects,
    mesh_uid,
    shard_name,
    write_shard,
)
from benchmark.scoring.data import BenchmarkData
from benchmark.scoring.protocol import write_predictions, write_results
from benchmark_fixture import make_dataset

ROOT = Path(__file__).resolve().parents[1]
MEMORY_LIMIT = 3 << 30  # address space of one CLI process (imports alone take ~1 GiB virtual)
TIMEOUT_S = 60
RECORD: list[dict] = []
PROGRESS = re.compile(r"^[\w ]+: +\d+%\|")  # a tqdm bar: progress, not an error line


def _limit():
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


def snapshot(*dirs: Path) -> dict:
    """Every file under ``dirs`` with its size and mtime (to see anything written)."""
    out = {}
    for d in dirs:
        for p in sorted(Path(d).rglob("*")) if Path(d).exists() else []:
            if p.is_file() or p.is_fifo():
                st = p.stat()
                out[str(p)] = (st.st_size, st.st_mtime_ns)
    return out


def cli(tool: str, *args, rc: int = 1, phrase: str, watch=(), env=None, preexec=_limit) -> str:
    """Run ``python -m <tool>.cli args`` bounded; assert a one-line refusal naming ``phrase``."""
    watch = [Path(w) for w in watch]
    before = snapshot(*watch)
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        [sys.executable, "-m", f"{tool}.cli", *map(str, args)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        cwd=ROOT,
        preexec_fn=preexec,
        env={**os.environ, **(env or {})},
    )
    try:
        out, err = proc.communicate(timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        raise AssertionError(f"{tool} {args}: no answer within {TIMEOUT_S} s") from None
    wall = time.perf_counter() - t0
    err = err.decode(errors="replace")
    lines = [line for line in err.splitlines() if line.strip() and not PROGRESS.match(line)]
    RECORD.append(
        {
            "case": f"{tool} {' '.join(map(str, args))}"[:160],
            "rc": proc.returncode,
            "seconds": round(wall, 3),
        }
    )
    assert proc.returncode == rc, (proc.returncode, err)
    assert len(lines) == 1 and "Traceback" not in err, err
    assert phrase in lines[0], (phrase, lines[0])
    assert lines[0].startswith(("basic-shapes", "radar-sim", "benchmark", "leaderboard")), lines[0]
    assert snapshot(*watch) == before, "something was written"
    return lines[0]


@pytest.fixture(scope="module", autouse=True)
def report():
    yield
    path = os.environ.get("HOSTILE_REPORT")
    if path:  # max RSS over every child process of this module (CLI cases and fixtures)
        peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss // 1024
        Path(path).write_text(
            json.dumps(
                {
                    "cli_cases": len(RECORD),
                    "max_seconds": max(r["seconds"] for r in RECORD),
                    "total_seconds": round(sum(r["seconds"] for r in RECORD), 2),
                    "peak_rss_mib_any_child": peak,
                    "memory_limit_gib": MEMORY_LIMIT / 2**30,
                    "cases": RECORD,
                },
                indent=1,
            )
        )


# --- shared fixtures ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ws(tmp_path_factory) -> dict:
    """A labelled dataset, a valid predictions file and its results, a board with it on."""
    root = tmp_path_factory.mktemp("hostile")
    data = make_dataset(root / "data", objects_per_class=2, n_test_per_class=1, n_shards=1)
    with BenchmarkData(data) as d:
        rows = d.mesh_rows("test")
        uids, fp, shape = d.meshes["uid"][rows], d.fingerprint, d.target_shape
        labels = d.label_fingerprint
        targets = np.stack([d.target(int(d.meshes["object"][r])) for r in rows]) + 1.0
    pred = root / "pred.h5"
    write_predictions(pred, fp, uids, targets, label_fingerprint=labels)
    from benchmark.scoring.evaluate import evaluate

    results = root / "results.json"
    write_results(results, evaluate(data, predictions=pred, progress=False))
    entries = root / "entries"
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "leaderboard.cli",
            "submit",
            results,
            "--predictions",
            pred,
            "--data",
            data,
            "--entries",
            entries,
            "--unregistered",
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert proc.returncode == 0, proc.stderr
    return {
        "root": root,
        "data": data,
        "pred": pred,
        "results": results,
        "entries": entries,
        "uids": uids,
        "targets": targets,
        "fp": fp,
        "labels": labels,
        "shape": shape,
    }


def predictions_file(path: Path, ws: dict, target=None, uid=None, attrs=None) -> Path:
    """A predictions file whose /target_db is made by ``target(f, name)`` (default: plain)."""
    with h5py.File(path, "w") as f:
        f.attrs.update(
            {
                "format": "basic-shapes-predictions",
                "version": 1,
                "dataset_fingerprint": ws["fp"],
                "label_fingerprint": ws["labels"],
                **(attrs or {}),
            }
        )
        (uid or (lambda f, n: f.create_dataset(n, data=ws["uids"])))(f, "mesh_uid")
        (target or (lambda f, n: f.create_dataset(n, data=ws["targets"])))(f, "target_db")
    return path


def shard_copy(ws: dict, name: str, edit=None, keep_fingerprint: bool = True) -> Path:
    """A copy of the dataset whose shard is edited by ``edit(h5py.File)`` in place."""
    d = ws["root"] / name
    shutil.copytree(ws["data"], d)
    if edit is not None:
        with h5py.File(d / shard_name(0), "r+") as f:
            edit(f)
    return d


@pytest.fixture(scope="module")
def servers():
    """An HTTP server and a TCP service with a banner: neither is a Dask scheduler."""

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args):
            pass

    http_srv = socketserver.TCPServer(("127.0.0.1", 0), Quiet)

    class Banner(socketserver.BaseRequestHandler):
        def handle(self):
            self.request.sendall(b"SSH-2.0-OpenSSH_9.6\r\n")
            time.sleep(0.5)

    banner = socketserver.ThreadingTCPServer(("127.0.0.1", 0), Banner)
    for srv in (http_srv, banner):
        threading.Thread(target=srv.serve_forever, daemon=True).start()
    yield {
        "http": f"tcp://127.0.0.1:{http_srv.server_address[1]}",
        "banner": f"127.0.0.1:{banner.server_address[1]}",
    }
    for srv in (http_srv, banner):
        srv.shutdown()
        srv.server_close()


def evaluate_refuses(ws, predictions, phrase, tmp: Path):
    out = tmp / "r.json"
    cli(
        "benchmark",
        "evaluate",
        "--quiet",
        "--data",
        ws["data"],
        "--predictions",
        predictions,
        "--out",
        out,
        phrase=phrase,
        watch=[tmp, ws["data"]],
    )
    assert not out.exists()


def submit_refuses(ws, results, predictions, phrase, data=None):
    return cli(
        "leaderboard",
        "submit",
        results,
        "--predictions",
        predictions,
        "--data",
        data or ws["data"],
        "--entries",
        ws["entries"],
        "--unregistered",
        phrase=phrase,
        watch=[ws["entries"], ws["data"]],
    )


# --- 1. file-read leaks through predictions --------------------------------------------------


def test_1_external_storage_is_refused_by_evaluate_and_submit(ws, tmp_path):
    def external(f, name):
        f.create_dataset(
            name, ws["targets"].shape, np.float32, external=[("/etc/passwd", 0, h5py.h5f.UNLIMITED)]
        )

    bad = predictions_file(tmp_path / "ext.h5", ws, target=external)
    evaluate_refuses(ws, bad, "/target_db uses external storage", tmp_path)
    submit_refuses(ws, ws["results"], bad, "/target_db uses external storage")


def test_1_fifo_predictions_and_fifo_external_targets_do_not_hang(ws, tmp_path):
    fifo = tmp_path / "fifo.h5"
    os.mkfifo(fifo)
    evaluate_refuses(ws, fifo, "fifo.h5: not a regular file", tmp_path)
    submit_refuses(ws, ws["results"], fifo, "not a regular file")

    def external(f, name):
        f.create_dataset(
            name, ws["targets"].shape, np.float32, external=[(str(fifo), 0, h5py.h5f.UNLIMITED)]
        )

    bad = predictions_file(tmp_path / "ext-fifo.h5", ws, target=external)
    submit_refuses(ws, ws["results"], bad, "external storage")


@pytest.mark.parametrize("kind", ["virtual", "soft", "external-link"])
def test_1_links_and_virtual_datasets_are_refused(ws, tmp_path, kind):
    src = ws["pred"]

    def target(f, name):
        if kind == "virtual":
            layout = h5py.VirtualLayout(ws["targets"].shape, np.float32)
            layout[:] = h5py.VirtualSource(str(src), "target_db", ws["targets"].shape)
            f.create_virtual_dataset(name, layout)
        elif kind == "soft":
            f.create_dataset("hidden", data=ws["targets"])
            f[name] = h5py.SoftLink("/hidden")
        else:
            f[name] = h5py.ExternalLink(str(src), "/target_db")

    bad = predictions_file(tmp_path / f"{kind}.h5", ws, target=target)
    phrase = "virtual dataset" if kind == "virtual" else "/target_db is a link"
    evaluate_refuses(ws, bad, phrase, tmp_path)


# --- 2. declared shapes are not trusted --------------------------------------------------------


@pytest.mark.parametrize("rows", [2 * 10**8, 10**9, 10**11])
def test_2_declared_rows_are_checked_against_the_file_size(ws, tmp_path, rows):
    def huge(f, name):
        f.create_dataset(name, (rows, *ws["shape"]), np.float32, chunks=(1, *ws["shape"]))

    def huge_uid(f, name):
        f.create_dataset(name, (rows,), np.int64, chunks=(1024,))

    bad = predictions_file(tmp_path / "bomb.h5", ws, target=huge, uid=huge_uid)
    assert bad.stat().st_size < 20_000
    t0 = time.perf_counter()
    submit_refuses(ws, ws["results"], bad, "declares")
    assert time.perf_counter() - t0 < 20  # interpreter start included; the check is ms


def test_2_compressed_bombs_are_bounded(ws, tmp_path):
    def zeros(f, name):  # 45 MB of zeros in ~50 kB: within deflate's ratio, so shape-checked
        f.create_dataset(
            name,
            data=np.zeros((20_000, *ws["shape"]), np.float32),
            chunks=(1000, *ws["shape"]),
            compression="gzip",
        )

    bad = predictions_file(tmp_path / "zip.h5", ws, target=zeros)
    evaluate_refuses(ws, bad, "/target_db is float32(20000", tmp_path)


def test_2_shard_declaring_a_billion_vertices_is_refused(ws):
    def huge(f):
        del f["meshes/vertices"]
        f["meshes"].create_dataset("vertices", (10**9, 3), np.float32, chunks=(4096, 3))

    d = shard_copy(ws, "bomb-shard", huge)
    cli("basic_shapes", "info", "--data", d, phrase="/meshes/vertices declares", watch=[d])


def test_2_radar_config_sizes_and_generate_capacity_are_bounded(ws, tmp_path):
    mesh = tmp_path / "box.obj"
    mesh.write_text(
        "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
    )
    for fields, phrase in [
        ({"n_aspect": 10**8}, "n_aspect <= 3601"),
        ({"n_aspect": 3601, "n_roll": 7200}, "memory"),
        ({"n_freq": 10**6, "n_range": 101}, "n_freq <= 65536"),
        ({"f_stop_hz": float("inf")}, "Infinity is not allowed"),
        ({"f_stop_hz": 1e13}, "f_stop_hz <= 1e+12"),
    ]:
        cfg = tmp_path / "cfg.json"
        cfg.write_text(json.dumps({"name": "huge", **fields}))
        cli(
            "radar_sim",
            "plot",
            mesh,
            "--config",
            cfg,
            "--out",
            tmp_path / "x.png",
            phrase=phrase,
            watch=[tmp_path],
        )
    cli(
        "basic_shapes",
        "generate",
        "--data",
        tmp_path / "g",
        "--objects-per-class",
        "17000",
        "--variants",
        "9",
        phrase="at most about",
        watch=[tmp_path],
    )
    assert not (tmp_path / "g").exists()


# --- 3. a submission must not break the board ----------------------------------------------


def _results(ws, tmp: Path, edit=None, text=None) -> Path:
    r = json.loads(ws["results"].read_text())
    if edit:
        edit(r)
    out = tmp / "results.json"
    out.write_text(text if text is not None else json.dumps(r))
    return out


@pytest.mark.parametrize(
    "case, edit, phrase",
    [
        ("huge params", lambda r: r["model"].__setitem__("params", 10**400), "model.params"),
        ("1e13 params", lambda r: r["model"].__setitem__("params", 10**13), "model.params"),
        ("extra field", lambda r: r.__setitem__("x", "y"), "unknown field(s) x"),
        (
            "extra model field",
            lambda r: r["model"].__setitem__("notes", "x"),
            "unknown field(s) notes",
        ),
        ("50 MB field", lambda r: r["model"].__setitem__("notes", "x" * 50_000_000), "larger than"),
        ("huge metric", lambda r: r["metrics"].__setitem__("simple_mse", 1e300), "simple_mse"),
        ("negative metric", lambda r: r["metrics"].__setitem__("complex_mse", -1.0), "complex_mse"),
        (
            "many classes",
            lambda r: r["metrics"]["per_class"].update(
                {f"c{i}": r["metrics"]["per_class"]["cube"] for i in range(100)}
            ),
            "per_class",
        ),
    ],
)
def test_3_results_with_hostile_fields_are_refused(ws, tmp_path, case, edit, phrase):
    submit_refuses(ws, _results(ws, tmp_path, edit), ws["pred"], phrase)


@pytest.mark.parametrize(
    "text, phrase",
    [
        ("[" * 100_000 + "]" * 100_000, "nested 100000 deep"),
        ('{"a": NaN}', "NaN is not allowed"),
        ('{"a": 1e999}', "out of range"),
        ("1" * 5000, "not valid JSON"),
    ],
)
def test_3_malformed_results_json_is_refused(ws, tmp_path, text, phrase):
    submit_refuses(ws, _results(ws, tmp_path, text=text), ws["pred"], phrase)


def test_3_swapped_files_are_named_for_what_they_are(ws):
    """The predictions file where the results JSON goes: said to be HDF5, not 'too large'."""
    submit_refuses(ws, ws["pred"], ws["pred"], "an HDF5 file, not JSON")


def test_3_duplicate_check_covers_the_content(ws, tmp_path):
    copy = tmp_path / "copy.h5"
    shutil.copyfile(ws["pred"], copy)
    with h5py.File(copy, "r+") as f:
        f.attrs["note"] = "one more attribute"
    submit_refuses(ws, ws["results"], copy, "already on the board")
    # rows in another order, another chunking: the same data scored
    order = np.arange(len(ws["uids"]))[::-1]
    shuffled = predictions_file(
        tmp_path / "shuffled.h5",
        ws,
        target=lambda f, n: f.create_dataset(n, data=ws["targets"][order], chunks=True),
        uid=lambda f, n: f.create_dataset(n, data=ws["uids"][order]),
    )
    submit_refuses(ws, ws["results"], shuffled, "already on the board")


def test_3_render_skips_bad_entries_with_one_warning_each(ws, tmp_path):
    entries = tmp_path / "entries"
    shutil.copytree(ws["entries"], entries)
    (good,) = entries.glob("*.json")
    entry = json.loads(good.read_text())
    bad = {
        "deep": "[" * 100_000 + "]" * 100_000,
        "params": json.dumps({**entry, "id": "bad-params", "params": 10**400}),
        "big": json.dumps({**entry, "id": "bad-big", "junk": "x" * 50_000_000}),
        "unknown": json.dumps({**entry, "id": "bad-unknown", "junk": 1}),
    }
    for name, text in bad.items():
        (entries / f"bad-{name}.json").write_text(text)
    site = tmp_path / "site"
    proc = subprocess.run(
        [sys.executable, "-m", "leaderboard.cli", "render", "--quiet", "--out", site]
        + ["--entries", entries],
        capture_output=True,
        text=True,
        cwd=ROOT,
        preexec_fn=_limit,
        timeout=TIMEOUT_S,
    )
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == len(bad), lines
    for line, name in zip(lines, sorted(bad)):
        assert f"bad-{name}.json" in line and "skipped" in line
    assert entry["name"] in (site / "LEADERBOARD.md").read_text()


# --- 4. generate touches only its own files ---------------------------------------------------


def test_4_generate_keeps_other_peoples_tmp_files(tmp_path):
    out = tmp_path / "g"
    out.mkdir()
    for name in ("notes.tmp", "paper.tex.tmp"):
        (out / name).write_text("mine")
    (out / "shard-00000.h5.tmp").write_text("a leftover of ours")
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "basic_shapes.cli",
            "generate",
            "--data",
            out,
            "--classes",
            "cube",
            "--objects-per-class",
            "1",
            "--variants",
            "0",
            "--workers",
            "0",
        ],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr
    assert "generate: 1 objects" in proc.stdout  # the plan (stdout), printed before the work
    assert sorted(p.name for p in out.iterdir()) == [
        "dataset.json",
        "notes.tmp",
        "paper.tex.tmp",
        "shard-00000.h5",
    ]
    assert (out / "notes.tmp").read_text() == "mine"


# --- 5. hangs ------------------------------------------------------------------------------------


def test_5_non_dask_schedulers_are_refused_within_seconds(ws, tmp_path, servers):
    for address, phrase in [
        (servers["http"], "no Dask handshake"),
        (servers["banner"], "not a Dask scheduler"),
    ]:
        t0 = time.perf_counter()
        cli(
            "basic_shapes",
            "generate",
            "--data",
            tmp_path / "g",
            "--classes",
            "cube",
            "--objects-per-class",
            "1",
            "--variants",
            "0",
            "--scheduler",
            address,
            phrase=phrase,
            watch=[tmp_path],
        )
        data = shard_copy(ws, f"label-{len(RECORD)}")
        cli(
            "radar_sim",
            "label",
            "--data",
            data,
            "--overwrite",
            "--scheduler",
            address,
            phrase=phrase,
            watch=[data],
        )
        assert time.perf_counter() - t0 < 40
    cli(
        "basic_shapes",
        "generate",
        "--data",
        tmp_path / "g",
        "--objects-per-class",
        "1",
        "--variants",
        "0",
        "--scheduler",
        "tcp://127.0.0.1:1",
        phrase="cannot connect",
        watch=[tmp_path],
    )


def test_5_negative_workers_are_refused(tmp_path, ws):
    cli(
        "basic_shapes",
        "generate",
        "--data",
        tmp_path / "g",
        "--workers",
        "-1",
        rc=2,
        phrase="argument --workers: '-1' must be >= 0",
        watch=[tmp_path],
    )
    cli(
        "radar_sim",
        "label",
        "--data",
        ws["data"],
        "--workers",
        "-1",
        rc=2,
        phrase="--workers",
        watch=[ws["data"]],
    )


# --- 6. shard integrity --------------------------------------------------------------------------


def _set(name, index, value):
    def edit(f):
        f[name][index] = value

    return edit


def _del_attr(name):
    def edit(f):
        del f.attrs[name]

    return edit


SHARD_CASES = {
    "offset -5": (_set("meshes/vertex_offset", 1, -5), "/meshes/vertex_offset is not a valid"),
    "offset 2^62": (_set("meshes/face_offset", 2, 2**62), "/meshes/face_offset is not a valid"),
    "offset down": (_set("meshes/face_offset", 3, 1), "/meshes/face_offset is not a valid"),
    "object index": (_set("meshes/object_index", 0, 99), "/meshes/object_index holds an index"),
    "class index": (_set("objects/class", 0, 7), "/objects/class holds an index"),
    "negative class": (_set("objects/class", 0, -1), "/objects/class holds an index"),
    "variant": (_set("meshes/variant", 1, 5000), "/meshes/variant holds a value"),
    "no generator_config": (_del_attr("generator_config"), "missing the generator_config"),
    "bad generator_config": (
        lambda f: f.attrs.__setitem__("generator_config", "{"),
        "generator_config: not valid JSON",
    ),
    "list generator_config": (
        lambda f: f.attrs.__setitem__("generator_config", "[]"),
        "generator_config is not a JSON object",
    ),
    "deep class names": (
        lambda f: f["objects/class"].attrs.__setitem__("names", "[" * 5000),
        "nested 5000 deep",
    ),
    "face index": (_set("meshes/faces", 0, [0, 1, 10**6]), "indexes a vertex outside its mesh"),
    "vertices edited": (
        _set("meshes/vertices", 0, [9.0, 9.0, 9.0]),
        "does not match its stored fingerprint",
    ),
}


@pytest.mark.parametrize("case", list(SHARD_CASES))
def test_6_inconsistent_shards_are_refused_by_evaluate(ws, tmp_path, case):
    edit, phrase = SHARD_CASES[case]
    d = shard_copy(ws, f"shard-{case.replace(' ', '-')}", edit)
    out = tmp_path / "r.json"
    cli(
        "benchmark",
        "evaluate",
        "--quiet",
        "--data",
        d,
        "--predictions",
        ws["pred"],
        "--out",
        out,
        phrase=phrase,
        watch=[tmp_path, d],
    )


def test_6_bad_offsets_are_refused_by_label_and_export(ws, tmp_path):
    d = shard_copy(ws, "offsets-label", _set("meshes/vertex_offset", 2, 2**62))
    cli(
        "radar_sim",
        "label",
        "--data",
        d,
        "--overwrite",
        "--workers",
        "1",
        phrase="vertex_offset",
        watch=[d],
    )
    cli(
        "basic_shapes",
        "export",
        "--data",
        d,
        "--out",
        tmp_path / "e",
        phrase="vertex_offset",
        watch=[d, tmp_path],
    )


def test_6_edited_shard_is_not_resumed_as_done(ws):
    from basic_shapes.generate import _is_done

    d = shard_copy(ws, "resume", _set("meshes/vertices", 3, [1.0, 2.0, 3.0]))
    with Shard(d / shard_name(0)) as s:
        config = s.config

    class Config:  # what _is_done compares: the config the shard was written with
        def to_dict(self):
            return config

    cfg = Config()
    assert not _is_done(d / shard_name(0), cfg)
    assert _is_done(ws["data"] / shard_name(0), cfg)
    label = cli(
        "radar_sim",
        "label",
        "--data",
        d,
        "--overwrite",
        "--workers",
        "1",
        phrase="does not match its stored fingerprint",
        watch=[d],
    )
    assert str(d / shard_name(0)) in label


def collinear_dataset(d: Path) -> Path:
    """One cube object whose only mesh has no face of non-zero area."""
    d.mkdir()
    v = np.array([[0, 0, 0], [1, 1, 1], [2, 2, 2], [3, 3, 3]], np.float32) * 0.1  # collinear
    obj = ObjectRecord(
        0,
        0,
        np.array([0.3, 0.3, 0.3]),
        1,
        "test",
        [MeshRecord(0, v, np.array([[0, 1, 2], [1, 2, 3]], np.int32), 0.0, {})],
    )
    write_shard(d / shard_name(0), [obj], ["cube"], {"fixture": True}, "0.1.0")
    return d


def test_10_label_of_a_bad_mesh_prints_one_line_not_a_dask_block(tmp_path):
    d = collinear_dataset(tmp_path / "bad")
    cli(
        "radar_sim",
        "label",
        "--data",
        d,
        "--workers",
        "1",
        "--mesh-labels",
        "all",
        phrase="object 0: mesh row 0: mesh has no face",
        watch=[d],
    )


# --- 7/10. one-line errors instead of tracebacks -------------------------------------------------


@pytest.mark.parametrize(
    "args, phrase",
    [
        (["--freq", "0", "--aspect", "0"], "frequencies must be > 0"),
        (["--freq", "-10", "--aspect", "0"], "frequencies must be > 0"),
        (["--freq", "10", "--aspect", "0", "--roll", "nan"], "argument --roll"),
        (["--freq", "10", "--aspect", "0:180:1e-9"], "at most 100000 values"),
        (["--freq", "10", "--aspect", "0:inf:1"], "argument --aspect"),
    ],
)
def test_7_rcs_flags(tmp_path, args, phrase):
    mesh = tmp_path / "t.obj"
    mesh.write_text("v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nf 1 2 3\n")
    cli("radar_sim", "rcs", mesh, *args, rc=2, phrase=phrase, watch=[tmp_path])


def test_7_plot_into_a_missing_directory(tmp_path, ws):
    cli(
        "radar_sim",
        "plot",
        "--data",
        ws["data"],
        "--object",
        "0",
        "--out",
        tmp_path / "missing/dir/x.png",
        rc=2,
        phrase="does not exist",
        watch=[tmp_path],
    )


@pytest.mark.parametrize(
    "args, phrase",
    [
        (["--min-scale-distance", "0"], "argument --min-scale-distance: '0' must be > 0"),
        (["--min-scale-distance", "nan"], "argument --min-scale-distance: 'nan' is not a finite"),
        (["--min-scale-distance", "-1"], "argument --min-scale-distance"),
        (["--seed", "-3"], "argument --seed: '-3' must be >= 0"),
        (["--scale-range", "0", "1"], "argument --scale-range"),
        (["--variants", "1000"], "argument --variants"),
        (["--objects-per-shard", "0"], "argument --objects-per-shard"),
        (["--scale-range", "2", "1"], "argument --scale-range: LOW 2 must be < HIGH 1"),
        (["--classes", ""], "argument --classes: '' names no class"),
        (["--classes", "cube,cube"], "argument --classes: 'cube,cube' names a class twice"),
        (["--classes", "box"], "argument --classes: unknown class box"),
    ],
)
def test_10_generate_flags_name_the_flag(tmp_path, args, phrase):
    cli(
        "basic_shapes",
        "generate",
        "--data",
        tmp_path / "g",
        *args,
        rc=2,
        phrase=phrase,
        watch=[tmp_path],
    )


def test_7_dataset_json_holding_a_list(tmp_path):
    out = tmp_path / "g"
    out.mkdir()
    (out / "dataset.json").write_text("[]")
    cli(
        "basic_shapes",
        "generate",
        "--data",
        out,
        "--objects-per-class",
        "1",
        "--variants",
        "0",
        phrase="dataset config is not a JSON object",
        watch=[tmp_path],
    )


def test_7_another_dataset_points_at_the_data_flag(tmp_path):
    out = tmp_path / "g"
    out.mkdir()
    (out / "dataset.json").write_text(json.dumps({"seed": 1}))
    cli(
        "basic_shapes",
        "generate",
        "--data",
        out,
        "--objects-per-class",
        "1",
        "--variants",
        "0",
        phrase="use another --data",
        watch=[tmp_path],
    )


def test_8_model_calling_sys_exit_0_is_an_error(ws, tmp_path):
    model = tmp_path / "quitter.py"
    model.write_text(
        "import sys\n\nclass Quitter:\n    name = 'quitter'\n\n"
        "    def predict(self, batch):\n        sys.exit(0)\n"
    )
    out = tmp_path / "r.json"
    line = cli(
        "benchmark",
        "evaluate",
        "--quiet",
        "--data",
        ws["data"],
        "--model",
        f"{model}:Quitter",
        "--out",
        out,
        phrase="quitter: predict failed: SystemExit",
        watch=[tmp_path],
    )
    assert "benchmark" in line and not out.exists()


def test_debug_flag_shows_the_traceback(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-m", "basic_shapes.cli", "info", "--data", tmp_path / "none", "--debug"],
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    assert proc.returncode == 1 and "Traceback" in proc.stderr
    proc = subprocess.run(
        [sys.executable, "-m", "basic_shapes.cli", "info", "--data", tmp_path / "none"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, infra.DEBUG_ENV: "1"},
    )
    assert "Traceback" in proc.stderr


# --- Python API -----------------------------------------------------------------------------------


def test_10_api_values_are_checked(ws):
    with pytest.raises(ValueError, match="object id -1 is negative"):
        mesh_uid(-1, 5)
    with pytest.raises(ValueError, match="split must be one of train, test"):
        next(iter_objects(ws["data"], split="tset"))
    with pytest.raises(infra.InputError, match="nested 100000 deep"):
        infra.load_json("[" * 100_000 + "]" * 100_000)
    with pytest.raises(infra.InputError, match="larger than"):
        infra.load_json("[" + "1," * 100 + "1]", max_bytes=100)
    assert infra.load_json('{"a": "[[[[", "b": [1, 2.5]}', max_depth=2) == {
        "a": "[[[[",
        "b": [1, 2.5],
    }


def test_boundary_turns_expected_and_unexpected_errors_into_one_line():
    from distributed import KilledWorker

    def raising(exc):
        def body(argv):
            raise exc

        return body

    for exc, phrase in [
        (KilledWorker("build-shard-3", "tcp://w:1", 3), "Dask worker died"),
        (MemoryError(), "out of memory"),
        (ShardError("x.h5: broken"), "x.h5: broken"),
        (
            FileNotFoundError(2, "No such file or directory", "a.h5"),
            "a.h5: No such file or directory",
        ),
        (
            OSError(
                28,
                "Can't synchronously write data (file write failed: time = "
                "Thu Nov 26 00:43:14 2026\n, filename = 'x.h5.tmp', errno "
                "= 28, error message = 'No space left on device')",
            ),
            "tool: error: No space left on device",
        ),
        (TypeError("bug\nmore"), "internal error: TypeError: bug"),
    ]:
        with pytest.raises(SystemExit) as info:
            infra.cli_boundary("tool", raising(exc), [])
        msg = str(info.value.code)
        assert msg.startswith("tool: error: ") and phrase in msg and "\n" not in msg, msg


def test_10_site_is_published_as_a_whole(tmp_path):
    from leaderboard.render import publish

    site = tmp_path / "site"
    publish(site, {"index.html": b"old", "LEADERBOARD.md": b"old"})
    (site / "CNAME").write_text("mine")
    with pytest.raises(OSError):  # fails half-way: the second file cannot be written
        publish(site, {"index.html": b"new", "no/such/dir.md": b"new"})
    assert (site / "index.html").read_bytes() == b"old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["site"]
    publish(site, {"index.html": b"new", "LEADERBOARD.md": b"new"})
    assert {p.name: p.read_bytes() for p in site.iterdir()} == {
        "index.html": b"new",
        "LEADERBOARD.md": b"new",
        "CNAME": b"mine",
    }


# --- 11. one error boundary (reliability audit): a dead child, a full disk, huge numbers, deep
# JSON, read-only data; each refused in one line naming the file (liveness: test_liveness.py)


def test_11_a_dead_meshlab_child_is_one_error_naming_the_object(tmp_path, monkeypatch):
    from basic_shapes.generate import ObjectPlan, build_shard
    from basic_shapes.meshlab_child import MeshLabChild

    def killed_child(*args):  # object_meshes whose MeshLab child is killed (out of memory)
        with MeshLabChild() as child:
            child._proc.kill()
            return child.apply("meshing_remove_duplicate_vertices", np.eye(3), [[0, 1, 2]])

    monkeypatch.setitem(
        sys.modules, "basic_shapes.blender", types.SimpleNamespace(object_meshes=killed_child)
    )
    shard = tmp_path / shard_name(0)
    with pytest.raises(
        OSError,
        match=rf"{shard}: object 7 \(cube\): MeshLab child died during "
        rf"meshing_remove_duplicate_vertices \(exit code -9\)",
    ):
        build_shard(
            str(shard), [ObjectPlan(7, "cube", 0, (0.5, 0.5, 0.5), 1, "train")], {"variants": 0}
        )
    assert not shard.exists()


def test_11_meshlab_child_prints_no_traceback_when_its_pipe_closes(capfd):
    import trimesh

    from basic_shapes.meshlab_child import MeshLabChild, _send

    sphere = trimesh.creation.icosphere(5)  # its answer (250 kB) overflows the pipe
    with MeshLabChild() as child:
        pipe = child._proc.stdin
        pipe.write(json.dumps(["meshing_remove_duplicate_vertices", {}]).encode() + b"\n")
        _send(pipe, np.asarray(sphere.vertices, np.float64))
        _send(pipe, np.asarray(sphere.faces, np.int32))
        pipe.flush()
        child._proc.stdout.close()  # as when its parent dies: the child's write fails
    assert child._proc.returncode != 0
    assert "Traceback" not in capfd.readouterr().err


def test_11_huge_coordinates_are_refused_not_overflowed(tmp_path):
    from radar_sim import MeshError, monostatic_field

    mesh = tmp_path / "huge.obj"
    mesh.write_text(
        "v 0 0 0\nv 1e30 0 0\nv 0 1e30 0\nv 0 0 1e30\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
    )
    cli(
        "radar_sim",
        "rcs",
        mesh,
        "--freq",
        "10",
        "--aspect",
        "0",
        phrase=f"{mesh}: coordinates too large",
        watch=[tmp_path],
    )
    with pytest.raises(MeshError, match="coordinates too large"):
        monostatic_field(np.eye(3) * 1e30, [[0, 1, 2]], np.array([1e10]), np.eye(3))


def _small_files():
    _limit()
    resource.setrlimit(resource.RLIMIT_FSIZE, (64, 64))  # a write beyond 64 bytes: EFBIG


def test_11_a_full_disk_names_the_file(tmp_path):
    out = tmp_path / "g"
    cli(
        "basic_shapes",
        "generate",
        "--data",
        out,
        "--objects-per-class",
        "1",
        "--variants",
        "0",
        phrase=f"{out / 'dataset.json'}: File too large",
        watch=[tmp_path],
        preexec=_small_files,
    )


def test_11_a_checksum_failure_names_the_file(ws, tmp_path):
    def checksummed(f, name):
        f.create_dataset(name, data=ws["targets"], chunks=(1, *ws["shape"]), fletcher32=True)

    bad = predictions_file(tmp_path / "sum.h5", ws, target=checksummed)
    with h5py.File(bad, "r") as f:
        offset = f["target_db"].id.get_chunk_info(0).byte_offset
    with open(bad, "r+b") as fh:
        fh.seek(offset + 100)
        byte = fh.read(1)
        fh.seek(offset + 100)
        fh.write(bytes([byte[0] ^ 0xFF]))
    evaluate_refuses(ws, bad, f"{bad}: /target_db cannot be read", tmp_path)


def test_11_a_degenerate_mesh_names_the_shard_and_the_mesh(tmp_path):
    d = collinear_dataset(tmp_path / "bad")
    cli(
        "radar_sim",
        "plot",
        "--data",
        d,
        "--object",
        "0",
        "--variant",
        "0",
        "--out",
        tmp_path / "x.png",
        phrase=f"{d / shard_name(0)}: object 0 variant 0: mesh has no face",
        watch=[tmp_path],
    )


def test_11_deeply_nested_shard_params_are_refused(ws):
    def deep(f):
        f["objects/params"][0] = "[" * 5000 + "]" * 5000
        f.attrs["fingerprint"] = content_fingerprint(f)  # a consistent, hostile shard

    d = shard_copy(ws, "deep-params", deep)
    cli(
        "radar_sim",
        "label",
        "--data",
        d,
        "--overwrite",
        "--workers",
        "0",
        phrase="/objects/params[0]: JSON nested 5000 deep",
        watch=[d],
    )


def test_11_checkpoint_config_is_read_with_a_bound(tmp_path):
    from benchmark.training.models.checkpoint import (
        CONFIG_MAX_BYTES,
        CheckpointError,
        load_checkpoint,
    )

    with open(tmp_path / "config.json", "wb") as fh:
        fh.truncate(4 * CONFIG_MAX_BYTES)  # sparse: costs no disk, and no memory to refuse
    with pytest.raises(CheckpointError, match="config.json: larger than"):
        load_checkpoint(tmp_path)


def _as_plain_user():
    """``_limit``; and as root, without the capabilities that override file modes."""
    _limit()
    if os.geteuid() == 0:
        libc = ctypes.CDLL(None, use_errno=True)
        for cap in (1, 2):  # CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH: out of the bounding set,
            if libc.prctl(24, cap, 0, 0, 0):  # PR_CAPBSET_DROP; so gone after exec
                raise OSError(ctypes.get_errno(), "prctl(PR_CAPBSET_DROP)")


def test_11_label_refuses_a_read_only_dataset_before_any_work(ws, monkeypatch):
    d = shard_copy(ws, "read-only")
    try:
        subprocess.run(["true"], preexec_fn=_as_plain_user, check=True)
    except (OSError, subprocess.SubprocessError):
        # root's file-mode override cannot be dropped here: the same refusal in this process,
        # with the permission check answering as it would for a plain user
        from radar_sim.config import RadarConfig
        from radar_sim.label import LabelError, LabelRequest, label_directory

        real_access = os.access
        monkeypatch.setattr(
            os,
            "access",
            lambda p, mode: False if Path(p) == d and mode == os.W_OK else real_access(p, mode),
        )
        before = snapshot(d)
        with pytest.raises(LabelError, match=f"{d}: not writable"):
            label_directory(
                d,
                LabelRequest(RadarConfig.named("xband-v1")),
                workers=0,
                overwrite=True,
                progress=False,
            )
        assert snapshot(d) == before
        return
    for path in [*d.glob("*.h5"), d]:
        path.chmod(0o555 if path.is_dir() else 0o444)
    try:  # refused before planning or simulating, not when the first label is written
        cli(
            "radar_sim",
            "label",
            "--data",
            d,
            "--overwrite",
            phrase=f"{d}: not writable",
            watch=[d],
            preexec=_as_plain_user,
        )
    finally:
        d.chmod(0o755)
