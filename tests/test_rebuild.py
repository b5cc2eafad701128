"""A recorded dataset version rebuilds byte for byte on another machine, or says where not.

``tiny-v3`` is a slice of everything a version holds: objects of every class, OOD meshes of
every remesher, labels. It is built here in fresh processes, once natively and once under an
emulated foreign CPU (numpy's AVX-512 loops off, OpenBLAS's generic Prescott kernels on one
thread, numba compiling for a generic x86-64, a different worker count and memory layout), and
both builds must equal the committed manifest (benchmark/manifests/tiny-v3.json) in every hash.
The old code failed exactly this: its scales came from numpy's exp, whose AVX-512 loop
rounds differently, and its labels from BLAS; later its distances from a BLAS dot product
(the bbox diagonal), which the Haswell kernel of the recording EPYC sums in another order
than an Intel AVX-512 host's SkylakeX kernel or Prescott (the foreign CPU was Haswell then,
the recording host's own kernel, so it could not see that).

Then the release path: pack the build, serve it on the loopback address, fetch it, and
refuse corrupted and foreign archives in one line with nothing left behind.
"""

from __future__ import annotations

import functools
import http.server
import io
import json
import os
import shutil
import subprocess
import sys
import tarfile
import threading
from pathlib import Path

import h5py
import numpy as np
import pytest

from basic_shapes import manifest as mf
from benchmark.scoring import versions

TINY = "tiny-v3"
"""The newest tiny version (xband-v3 labels); its meshes are tiny-v2's."""
FOREIGN_CPU = {
    "NPY_DISABLE_CPU_FEATURES": "AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL "
    "AVX512_SPR",
    "OPENBLAS_CORETYPE": "Prescott",  # neither the recording host's kernel nor an AVX-512 one
    "OPENBLAS_NUM_THREADS": "1",
    "NUMBA_CPU_NAME": "generic",
}


def dataset_cli(*args, env=None, cwd=None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "benchmark.cli", "dataset", *args],
        capture_output=True,
        text=True,
        env={**os.environ, **(env or {})},
        cwd=cwd,
    )


@pytest.fixture(scope="module")
def tiny(tmp_path_factory) -> Path:
    """TINY built natively on 2 workers (fresh processes)."""
    data = tmp_path_factory.mktemp("tiny") / TINY
    proc = dataset_cli(TINY, "--data", str(data), "--workers", "2", "--quiet")
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report["matches_recorded"] is True, report["differences"]
    assert report["mesh"] == versions.get(TINY).fingerprints["mesh"]
    return data


def test_tiny_v1_is_a_slice_of_everything(tiny):
    """Every class, test objects with OOD meshes of all three remeshers, and labels."""
    expected = versions.get(TINY).manifest
    variants = {m["variant"] for s in expected["shards"] for o in s["objects"] for m in o["meshes"]}
    assert {0, 1, 2} <= variants
    assert {v // 25 for v in variants if v >= 900} == {36, 37, 38}  # isotropic, qem, delaunay
    assert all("label" in o for s in expected["shards"] for o in s["objects"])


def test_rebuild_under_a_foreign_cpu_matches_the_manifest(tmp_path):
    """Another CPU's arithmetic, one worker, another memory layout: the same bytes."""
    data = tmp_path / "foreign"
    env = {**FOREIGN_CPU, "PADDING": "x" * 4099}  # moves the stack and environment
    setarch = shutil.which("setarch")
    cmd = [
        sys.executable,
        "-m",
        "benchmark.cli",
        "dataset",
        TINY,
        "--data",
        str(data),
        "--workers",
        "1",
        "--quiet",
    ]
    if setarch and subprocess.run([setarch, "x86_64", "-R", "true"]).returncode == 0:
        cmd = [setarch, "x86_64", "-R", *cmd]  # no address randomization at all
    proc = subprocess.run(cmd, capture_output=True, text=True, env={**os.environ, **env})
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report["matches_recorded"] is True, report["differences"]


@pytest.fixture
def altered(tiny, tmp_path) -> Path:
    """TINY with one vertex of object 2, variant 1 in shard 0 moved by one float32 ulp (its
    stored fingerprint kept)."""
    data = tmp_path / "altered"
    shutil.copytree(tiny, data)
    with h5py.File(data / "shard-00000.h5", "r+") as f:
        oi, var = f["meshes/object_index"][()], f["meshes/variant"][()]
        row = int(np.flatnonzero((oi == 2) & (var == 1))[0])
        start = int(f["meshes/vertex_offset"][row])
        v = f["meshes/vertices"][start]
        f["meshes/vertices"][start] = np.nextafter(v, np.float32(np.inf))
    return data


def test_check_names_the_altered_mesh(altered):
    """--check names shard, object, variant and that the vertices differ, exit 1, one line on
    stderr."""
    proc = dataset_cli(TINY, "--check", "--data", str(altered))
    assert proc.returncode == 1
    error = proc.stderr.strip()
    assert error.count("\n") == 0
    object_id = versions.get(TINY).manifest["shards"][0]["objects"][2]["id"]
    assert f"shard-00000.h5 object {object_id} mesh variant 1: vertices differ" in error
    report = json.loads(proc.stdout)
    assert report["matches_recorded"] is False
    assert any("stored fingerprints" in d for d in report["differences"])


def test_a_folded_manifest_names_the_altered_object(tiny, altered):
    """Above PER_MESH_LIMIT meshes a manifest keeps one hash over each object's meshes: a
    fresh manifest of the same build matches it from either side, and the altered vertex is
    named by its object."""
    full = mf.build(tiny, TINY)
    assert mf.fold_meshes(full) is full  # tiny is far below the limit
    folded = json.loads(mf.dumps(mf.fold_meshes(full, limit=0)))
    assert mf.fold_meshes(folded, limit=0) == folded  # folding twice changes nothing
    objects = [o for s in folded["shards"] for o in s["objects"]]
    assert all(set(o["meshes"]) == {"count", "hash"} for o in objects)
    assert len(mf.dumps(folded)) < len(mf.dumps(full)) / 2
    again = mf.build(tiny, TINY)
    assert mf.differences(folded, again) == [] and mf.differences(again, folded) == []
    found = mf.differences(folded, mf.build(altered, TINY))
    object_id = folded["shards"][0]["objects"][2]["id"]
    assert found[0].startswith(f"shard-00000.h5 object {object_id}: meshes differ")
    assert not any("variant" in d for d in found)
    assert mf.differences(mf.build(altered, TINY), folded)[0] == found[0]


def test_check_names_an_altered_label(tiny, tmp_path):
    data = tmp_path / "relabelled"
    shutil.copytree(tiny, data)
    with h5py.File(data / "shard-00000.h5", "r+") as f:
        f["radar/response"][1] = f["radar/response"][1] * np.complex64(10)
    proc = dataset_cli(TINY, "--check", "--data", str(data))
    assert proc.returncode == 1
    object_id = versions.get(TINY).manifest["shards"][0]["objects"][1]["id"]
    assert f"object {object_id}: label differs" in proc.stderr


def test_check_names_edited_radar_axes_and_dataset_json(tiny, tmp_path):
    """The radar axes stored beside the labels and dataset.json are outside the fingerprints:
    --check compares them with the version's radar config and the recorded dataset.json."""
    data = tmp_path / "edited"
    shutil.copytree(tiny, data)
    with h5py.File(data / "shard-00000.h5", "r+") as f:
        f["radar/aspect"][1] += 5.0
    config = json.loads((data / "dataset.json").read_text())
    (data / "dataset.json").write_text(json.dumps({**config, "seed": config["seed"] + 1}))
    proc = dataset_cli(TINY, "--check", "--data", str(data))
    assert proc.returncode == 1
    differences = json.loads(proc.stdout)["differences"]
    assert f"dataset.json differs: seed is {config['seed'] + 1}, recorded {config['seed']}" in (
        differences
    )
    assert any(d.startswith("shard-00000.h5: radar axes differ") for d in differences)
    assert "aspect_deg" in " ".join(differences) and "roll_deg" not in " ".join(differences)


def test_the_board_refuses_a_version_relabelled_consistently(tiny, tmp_path):
    """Labels edited and their fingerprints stamped again: the data is self-consistent but is
    not the recorded version, so the public board refuses it; a private board takes it as no
    version."""
    from basic_shapes.shards import Shard
    from benchmark.scoring.data import BenchmarkData
    from leaderboard import cli as board

    data = tmp_path / "relabelled"
    shutil.copytree(tiny, data)
    shard = data / "shard-00000.h5"
    with h5py.File(shard, "r+") as f:
        f["radar/response"][0] = f["radar/response"][0] * np.complex64(3)
    with Shard(shard) as s:
        stamp = s.radar.computed_fingerprint()
    with h5py.File(shard, "r+") as f:
        f["radar"].attrs["label_fingerprint"] = stamp
    with BenchmarkData(data) as d:
        assert d.label_fingerprint != versions.get(TINY).fingerprints["label"]
    submit = _submission(data, tmp_path)
    with pytest.raises(SystemExit) as exc:
        board.main(submit)
    assert f"follows {TINY}'s recipe, but its fingerprints" in str(exc.value.code)
    assert not (tmp_path / "entries").exists()
    board.main([*submit, "--unregistered"])
    (entry,) = (tmp_path / "entries").glob("*.json")
    assert json.loads(entry.read_text())["dataset"]["version"] is None


def _submission(data: Path, tmp_path: Path) -> list[str]:
    """``leaderboard submit``'s arguments for a constant -30 dB prediction of every test mesh
    of ``data``, its results written by ``benchmark evaluate``; entries go to tmp_path."""
    from benchmark.scoring.data import BenchmarkData
    from benchmark.scoring.protocol import write_predictions

    with BenchmarkData(data) as d:
        test = d.object_rows("test")
        rows = np.concatenate([r for o in test for r in (d.meshes_of(o), d.ood_meshes_of(o))])
        uids = d.meshes["uid"][rows]
        shape, fingerprints = d.target_shape, (d.fingerprint, d.label_fingerprint)
    preds, results = tmp_path / "p.h5", tmp_path / "r.json"
    write_predictions(
        preds,
        fingerprints[0],
        uids,
        np.full((len(uids), *shape), -30.0, np.float32),
        label_fingerprint=fingerprints[1],
    )
    evaluate = [sys.executable, "-m", "benchmark.cli", "evaluate", "--data", str(data)]
    evaluate += ["--predictions", str(preds), "--out", str(results), "--speed-ms", "1"]
    proc = subprocess.run(evaluate, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    submit = ["submit", str(results), "--predictions", str(preds), "--data", str(data)]
    return [*submit, "--entries", str(tmp_path / "entries"), "--name", "x"]


class _Quiet(http.server.SimpleHTTPRequestHandler):
    def log_message(self, *args):
        pass


@pytest.fixture
def server(tmp_path):
    """A static HTTP server on the loopback address, serving ``tmp_path/www``."""
    root = tmp_path / "www"
    root.mkdir()
    httpd = http.server.ThreadingHTTPServer(
        ("127.0.0.1", 0), functools.partial(_Quiet, directory=str(root))
    )
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield root, f"http://127.0.0.1:{httpd.server_address[1]}"
    httpd.shutdown()
    httpd.server_close()


def test_pack_then_fetch_over_http_gives_the_recorded_bytes(tiny, server, tmp_path):
    root, url = server
    proc = dataset_cli(TINY, "--pack", str(root / f"{TINY}.tar"), "--data", str(tiny))
    assert proc.returncode == 0, proc.stderr
    target = tmp_path / "fetched"
    proc = dataset_cli(TINY, "--from", f"{url}/{TINY}.tar", "--data", str(target), "--quiet")
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report["matches_recorded"] is True
    assert report["mesh"] == versions.get(TINY).fingerprints["mesh"]
    recorded = versions.get(TINY).manifest
    for shard in recorded["shards"]:
        assert mf.file_sha256(target / shard["name"]) == shard["sha256"]
    # packing is deterministic: the same directory gives the same archive bytes
    again = dataset_cli(TINY, "--pack", str(tmp_path / "again.tar"), "--data", str(target))
    assert again.returncode == 0
    assert mf.file_sha256(tmp_path / "again.tar") == mf.file_sha256(root / f"{TINY}.tar")


def _tar(path: Path, members: dict[str, bytes]) -> None:
    with tarfile.open(path, "w") as tar:
        for name, data in members.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))


def test_corrupted_and_foreign_archives_are_refused(tiny, server, tmp_path):
    root, url = server
    good = root / "good.tar"
    assert dataset_cli(TINY, "--pack", str(good), "--data", str(tiny)).returncode == 0
    with tarfile.open(good) as tar:
        members = {m.name: tar.extractfile(m).read() for m in tar.getmembers()}
    shard = bytearray(members["shard-00000.h5"])
    shard[len(shard) // 2] ^= 0x01  # one flipped bit in the shard
    _tar(root / "flipped.tar", {**members, "shard-00000.h5": bytes(shard)})
    _tar(root / "foreign.tar", {"notes.txt": b"hello"})
    _tar(root / "escape.tar", {**members, "../evil.h5": b"x"})
    (root / "truncated.tar").write_bytes(good.read_bytes()[:5000])
    cases = {
        "flipped.tar": "does not match the sha256",
        "foreign.tar": "unexpected member",
        "escape.tar": "unexpected member",
        "truncated.tar": "tar",
        "missing.tar": "cannot download",
    }
    for name, message in cases.items():
        target = tmp_path / f"out-{name}"
        proc = dataset_cli(TINY, "--from", f"{url}/{name}", "--data", str(target), "--quiet")
        assert proc.returncode == 1, name
        assert message in proc.stderr and proc.stderr.strip().count("\n") == 0, proc.stderr
        assert not target.exists(), name
        assert not any(p.name.startswith(".out-") for p in tmp_path.iterdir()), name
    assert not (tmp_path / "evil.h5").exists()


def test_fetch_refuses_a_directory_that_holds_data(tiny, tmp_path):
    target = tmp_path / "busy"
    target.mkdir()
    (target / "keep.txt").write_text("mine")
    proc = dataset_cli(TINY, "--from", str(tmp_path / "none.tar"), "--data", str(target))
    assert proc.returncode == 1 and "not empty" in proc.stderr
    assert (target / "keep.txt").read_text() == "mine"


def test_a_slice_of_shards_builds_and_checks_shard_by_shard(tiny, tmp_path):
    """--shards selects shards, checked against those of the manifest (TINY has one shard,
    resumed here from a copy of the build; slices of many-shard versions are built from
    scratch in the slow set)."""
    data = tmp_path / "slice"
    shutil.copytree(tiny, data)
    proc = dataset_cli(TINY, "--data", str(data), "--shards", "0", "--workers", "0", "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["matches_recorded"] is True
    proc = dataset_cli(TINY, "--data", str(tmp_path / "x"), "--shards", "7", "--quiet")
    assert proc.returncode == 1 and "shard 7 does not exist" in proc.stderr
    proc = dataset_cli(TINY, "--data", str(data), "--shards", "0", "--check")
    assert proc.returncode == 1 and "--shards selects what to build" in proc.stderr


@pytest.mark.slow  # two shards of real Blender, remeshing and labelling: CI's slow set
@pytest.mark.parametrize("version", ["hidden-cpu-v3", "hidden-cpu-v4"])
def test_hidden_slice_with_both_families_rebuilds(tmp_path, version):
    """Shards 56 (test frustums) and 187 (test rounded boxes), with their OOD meshes and
    labels, rebuild under the emulated foreign CPU to the recorded manifest (xband-v2 and
    xband-v3 labels of the same meshes); the board refuses the slice as a slice."""
    from leaderboard import cli as board

    data = tmp_path / version
    proc = dataset_cli(
        version,
        "--data",
        str(data),
        "--shards",
        "56,187",
        "--workers",
        "1",
        "--quiet",
        env=FOREIGN_CPU,
    )
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout)
    assert report["matches_recorded"] is True, report["differences"]
    expected = versions.get(version).manifest["shards"]
    ood = {
        m["variant"] // 25
        for i in (56, 187)
        for o in expected[i]["objects"]
        for m in o["meshes"]
        if m["variant"] >= 900
    }
    assert ood == {36, 37, 38}  # isotropic, qem (rounded boxes) and delaunay (both)
    with pytest.raises(SystemExit) as exc:  # the public board takes whole builds only
        board.main(_submission(data, tmp_path))
    assert f"a slice of {version} (2 of {len(expected)} shards)" in str(exc.value.code)
    assert not (tmp_path / "entries").exists()


@pytest.mark.parametrize("version", ["tiny-v2", TINY])
def test_labels_rebuild_from_stripped_meshes_without_blender(tiny, tmp_path, version):
    """perf/label_rebuild.py: the meshes copied without /radar, labelled again in a process
    where bpy cannot be imported, give the manifest's label fingerprints (tiny-v2's labels,
    numpy's FFT, and tiny-v3's, the portable DFT, from the same meshes); a label left
    behind would make the check vacuous, so the stripped copy must hold none."""
    assert versions.get(version).fingerprints["mesh"] == versions.get(TINY).fingerprints["mesh"]
    script = Path(__file__).resolve().parents[1] / "perf" / "label_rebuild.py"
    stripped = tmp_path / "stripped"
    run = functools.partial(subprocess.run, capture_output=True, text=True)
    proc = run(
        [
            sys.executable,
            script,
            "strip",
            version,
            "--data",
            tiny,
            "--shards",
            "0",
            "--into",
            stripped,
        ]
    )
    assert proc.returncode == 0, proc.stderr
    with h5py.File(stripped / "shard-00000.h5", "r") as f:
        assert "radar" not in f and "meshes" in f
    block = tmp_path / "block"
    block.mkdir()
    (block / "sitecustomize.py").write_text("import sys\nsys.modules['bpy'] = None\n")
    out = tmp_path / "rebuild.json"
    proc = run(
        [sys.executable, script, "check", f"{version}={stripped}", "--workers", "1", "--out", out],
        env={
            **os.environ,
            "PYTHONPATH": os.pathsep.join([str(block), os.environ.get("PYTHONPATH", "")]),
        },
    )
    assert proc.returncode == 0, proc.stderr
    (result,) = json.loads(out.read_text())["versions"]
    recorded = versions.get(version).manifest["shards"][0]["label_fingerprint"]
    assert result["shards"] == [
        {
            "shard": "shard-00000.h5",
            "label_fingerprint": recorded,
            "matches": True,
            "objects": len(versions.get(version).manifest["shards"][0]["objects"]),
        }
    ]
