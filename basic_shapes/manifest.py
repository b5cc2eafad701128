"""Dataset manifests: what a dataset version's bytes are, shard by shard and object by object.

A manifest proves a build (docs/DATASETS.md, "Identity"). It holds, per shard, the file's
sha256 and its mesh and label fingerprints, and per object short hashes of its record (class,
scale, seed, split, hidden parameters), of each mesh's vertices, faces and record, of its label
and of any stored per-mesh physics. ``differences`` compares a directory's manifest with it and
names the first shard, object and mesh that differ and which data (a mesh's "record" is its
generator parameters and measured distances): a rebuild that does not match says where. A
version of more than PER_MESH_LIMIT meshes records one hash over each object's meshes instead
(``fold_meshes``; paper-v3 has 302,700 meshes), and a rebuild that differs is then named down
to the object. Hashes are of array bytes (dtype and C order fixed by the shard format), so
they do not depend on the HDF5 library that wrote the file; the file hashes do, and are what
a release archive is checked against.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import numpy as np

from basic_shapes.infra import load_json
from basic_shapes.shards import Shard, ShardError, list_shards

FORMAT = 1
SHORT = 16  # hex digits of the per-object and per-mesh hashes: enough to tell which differs
PER_MESH_LIMIT = 50_000  # meshes; a larger version's manifest folds each object's meshes
LIMIT = 10  # differences reported: the first ones say where, the rest repeat


def _short(*arrays) -> str:
    h = hashlib.sha256()
    for a in arrays:
        h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:SHORT]


def file_sha256(path: str | os.PathLike) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _shard_entry(path: Path) -> dict:
    """One shard's entry, from its content: fingerprints recomputed, not read back, so an
    edit shows as the object and mesh it touched even where the stored fingerprint was kept."""
    with Shard(path) as s:
        objs, table = s.objects(), s.mesh_table()
        labels = s.radar if s.has_labels else None
        physics = {} if labels is None else {int(r): j for j, r in enumerate(labels.mesh_index)}
        params, measured = s.object_params_text(), s.mesh_measures()
        objects = []
        for k in range(s.n_objects):
            record = [
                objs["id"][k],
                objs["class"][k],
                objs["scale"][k],
                objs["seed"][k],
                np.bytes_(objs["split"][k]),
            ]
            if params is not None:
                record.append(np.bytes_(params[k]))
            meshes = []
            for i in np.flatnonzero(table["object_index"] == k):
                v, f = s.mesh(int(i))
                mesh = {
                    "variant": int(table["variant"][i]),
                    "vertices": _short(v),
                    "faces": _short(f),
                    "record": _short(
                        *(np.bytes_(m[i]) if m.dtype.kind == "O" else m[i] for m in measured)
                    ),
                }
                if int(i) in physics:
                    mesh["physics"] = _short(labels.mesh_response(physics[int(i)]))
                meshes.append(mesh)
            entry = {"id": int(objs["id"][k]), "record": _short(*record), "meshes": meshes}
            if labels is not None:
                entry["label"] = _short(labels.response(k))
            objects.append(entry)
        entry = {
            "name": path.name,
            "sha256": file_sha256(path),
            "fingerprint": s.computed_fingerprint(),
            "label_fingerprint": labels.computed_fingerprint() if labels else None,
            "objects": objects,
        }
        stored = (s.fingerprint, labels.fingerprint if labels else None)
        if stored != (entry["fingerprint"], entry["label_fingerprint"]):
            entry["stored_fingerprints_differ"] = True
        return entry


def build(
    directory: str | os.PathLike, version: str | None = None, stack: dict | None = None
) -> dict:
    """The manifest of a dataset directory. Its mesh and label fingerprints are those of
    ``shards.dataset_fingerprint`` and ``label_fingerprint``, computed from the content."""
    shards = [_shard_entry(p) for p in list_shards(directory)]
    labelled = all(s["label_fingerprint"] for s in shards)
    config = Path(directory) / "dataset.json"
    settings = load_json(config, max_bytes=1 << 16, error=ShardError) if config.exists() else None
    if settings is not None and not isinstance(settings, dict):
        raise ShardError(f"{config}: not a JSON object")
    return {
        "format": FORMAT,
        "version": version,
        "stack": stack or {},
        "config": settings,
        "fingerprints": {
            "mesh": _combined(s["fingerprint"] for s in shards),
            "label": _combined(s["label_fingerprint"] for s in shards) if labelled else None,
        },
        "shards": shards,
    }


def fold_meshes(manifest: dict, limit: int = PER_MESH_LIMIT) -> dict:
    """``manifest`` with each object's per-mesh entries folded into their count and one hash
    when it holds more than ``limit`` meshes (unchanged otherwise)."""
    meshes = [o["meshes"] for s in manifest["shards"] for o in s["objects"]]
    if sum(m["count"] if isinstance(m, dict) else len(m) for m in meshes) <= limit:
        return manifest
    shards = [
        {**s, "objects": [{**o, "meshes": _folded(o["meshes"])} for o in s["objects"]]}
        for s in manifest["shards"]
    ]
    return {**manifest, "shards": shards}


def _folded(meshes: list | dict) -> dict:
    """One object's meshes as {"count", "hash"} (already folded: as they are)."""
    if isinstance(meshes, dict):
        return meshes
    text = json.dumps(meshes, sort_keys=True).encode()
    return {"count": len(meshes), "hash": hashlib.sha256(text).hexdigest()[:SHORT]}


def _combined(fingerprints) -> str:
    h = hashlib.sha256()
    for fp in fingerprints:
        h.update(fp.encode())
    return h.hexdigest()


def dumps(manifest: dict) -> str:
    """One line per object, so a diff of two manifests reads object by object."""
    head = {k: v for k, v in manifest.items() if k != "shards"}
    lines = ["{" + json.dumps(head, sort_keys=True)[1:-1] + ', "shards": [']
    for si, shard in enumerate(manifest["shards"]):
        meta = {k: v for k, v in shard.items() if k != "objects"}
        lines.append("  {" + json.dumps(meta, sort_keys=True)[1:-1] + ', "objects": [')
        rows = [f"    {json.dumps(o, sort_keys=True)}" for o in shard["objects"]]
        lines.append(",\n".join(rows))
        lines.append("  ]}" + ("," if si < len(manifest["shards"]) - 1 else ""))
    lines.append("]}")
    return "\n".join(lines) + "\n"


def differences(expected: dict, found: dict, limit: int = LIMIT) -> list[str]:
    """Where ``found`` (a manifest of a directory) differs from ``expected``: shard, object,
    mesh and data, first difference first; [] when they agree (file hashes aside)."""
    out: list[str] = []
    names_e = [s["name"] for s in expected["shards"]]
    names_f = [s["name"] for s in found["shards"]]
    if names_e != names_f:
        missing = sorted(set(names_e) - set(names_f))
        extra = sorted(set(names_f) - set(names_e))
        parts = [f"missing {missing[:3]}"] if missing else []
        parts += [f"unexpected {extra[:3]}"] if extra else []
        out.append(f"shards differ: {', '.join(parts) or 'the same names in another order'}")
    for se, sf in zip(expected["shards"], found["shards"]):
        if se["name"] != sf["name"]:
            continue
        where = se["name"]
        if len(se["objects"]) != len(sf["objects"]):
            out.append(f"{where}: {len(sf['objects'])} objects, expected {len(se['objects'])}")
            continue
        for oe, of in zip(se["objects"], sf["objects"]):
            out += _object_differences(f"{where} object {oe['id']}", oe, of)
        if sf.get("stored_fingerprints_differ"):
            out.append(f"{where}: content does not match its stored fingerprints (edited)")
            if len(out) >= limit:
                return out
        if not out and se["label_fingerprint"] != sf["label_fingerprint"]:
            out.append(f"{where}: label fingerprint differs (radar config or simulation rule)")
    out += _config_differences(expected.get("config"), found.get("config"))
    if not out:
        for kind in ("mesh", "label"):
            if expected["fingerprints"].get(kind) != found["fingerprints"].get(kind):
                out.append(f"{kind} fingerprint differs")
    return out[:limit]


def _config_differences(expected: dict | None, found: dict | None) -> list[str]:
    """dataset.json against the recorded one, the toolkit's version aside (a rebuild by a
    later release of the same recipe is the same dataset)."""
    if expected is None:
        return []
    if found is None:
        return ["dataset.json is missing"]
    keys = sorted(
        k
        for k in set(expected) | set(found)
        if k != "toolkit_version" and expected.get(k) != found.get(k)
    )
    return [
        f"dataset.json differs: {k} is {found.get(k)!r}, recorded {expected.get(k)!r}" for k in keys
    ]


def _object_differences(obj: str, oe: dict, of: dict) -> list[str]:
    """``differences`` of one object's manifest entry, named ``obj``."""
    if oe["id"] != of["id"]:
        return [f"{obj}: found object {of['id']} in its place"]
    out = []
    if oe["record"] != of["record"]:
        out.append(f"{obj}: record differs (class, scale, seed, split or parameters)")
    out += _mesh_differences(obj, oe["meshes"], of["meshes"])
    if oe.get("label") != of.get("label"):
        out.append(f"{obj}: label differs")
    return out


def _mesh_differences(obj: str, expected: list | dict, found: list | dict) -> list[str]:
    if isinstance(expected, dict) or isinstance(found, dict):  # folded: one hash for them all
        expected, found = _folded(expected), _folded(found)
        if found == expected:
            return []
        return [
            f"{obj}: meshes differ ({found['count']} meshes, expected {expected['count']}; "
            "the manifest keeps one hash over an object's meshes, not which one)"
        ]
    variants_e = [m["variant"] for m in expected]
    variants_f = [m["variant"] for m in found]
    if variants_e != variants_f:
        return [f"{obj}: variants {variants_f}, expected {variants_e}"]
    out = []
    for me, mf in zip(expected, found):
        data = [k for k in ("vertices", "faces", "record", "physics") if me.get(k) != mf.get(k)]
        if data:
            plural = len(data) > 1 or data[0] in ("vertices", "faces")
            verb = "differ" if plural else "differs"
            out.append(f"{obj} mesh variant {me['variant']}: {', '.join(data)} {verb}")
    return out


def load(path: str | os.PathLike) -> dict:
    manifest = load_json(Path(path), max_bytes=1 << 28, error=ShardError)
    if (
        not isinstance(manifest, dict)
        or manifest.get("format") != FORMAT
        or not isinstance(manifest.get("shards"), list)
    ):
        raise ShardError(f"{path}: not a dataset manifest of format {FORMAT}")
    return manifest
