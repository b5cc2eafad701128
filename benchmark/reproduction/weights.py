"""`benchmark weights`: a reproduce folder's trained weights as a release archive, and back.

Every number of a committed table rests on trained weights that are too large for git (24 MB
per run of the cpu preset, 51 runs). ``--pack ARCHIVE`` writes the folder's checkpoints
(``checkpoints/<row>/seed-<s>/model.pt`` and ``config.json``, nothing else) into one
uncompressed tar, and the manifest of their sha256 hashes beside them as ``weights.json``:
the manifest is committed with the table (docs/results/<version>/weights.json), the archive
published anywhere (a Hugging Face or Zenodo record, a plain web server). ``--from SOURCE
--manifest weights.json`` fetches an archive (path, file:// or http(s) URL), accepts it only if
it holds exactly the manifest's files with their hashes, and unpacks it atomically into a new
``--out`` folder. ``benchmark reproduce --preset P --data D --out OUT`` then trains nothing:
every run finds its checkpoint (same config, same dataset) and is only evaluated, which
rebuilds the per-object errors, the predictions and the table from the released weights.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from basic_shapes.infra import add_quiet_flag, atomic_path, load_json
from basic_shapes.manifest import file_sha256

FORMAT = 1
MANIFEST = "weights.json"
FILES = ("model.pt", "config.json")  # per run: what ``benchmark reproduce`` reuses
MAX_MANIFEST_BYTES = 1 << 20


class WeightsError(ValueError):
    """A folder with nothing to pack, or a manifest that is not one."""


def manifest(out: str | Path) -> dict:
    """The hashes of every run's checkpoint files under ``out``, and the dataset they were
    trained on (one dataset per folder, as ``benchmark reproduce`` writes it)."""
    out = Path(out)
    runs = sorted(p.parent for p in out.glob("checkpoints/*/seed-*/model.pt"))
    if not runs:
        raise WeightsError(f"{out}: no checkpoints/<row>/seed-<s>/model.pt to pack")
    files, datasets = {}, set()
    for run in runs:
        for name in FILES:
            path = run / name
            if not path.is_file():
                raise WeightsError(f"{run}: no {name}")
            files[path.relative_to(out).as_posix()] = file_sha256(path)
        datasets.add(load_json(run / "config.json", max_bytes=1 << 24).get("dataset_fingerprint"))
    if len(datasets) != 1:
        raise WeightsError(f"{out}: checkpoints of {len(datasets)} datasets; pack one at a time")
    return {"format": FORMAT, "dataset_fingerprint": datasets.pop(), "files": files}


def pack(out: str | Path, archive: str | Path) -> dict:
    """Write the archive and ``out/weights.json``; return the manifest."""
    from basic_shapes import release

    found = manifest(out)
    release.pack_files(out, list(found["files"]), archive)
    found["archive_sha256"] = file_sha256(archive)
    with atomic_path(Path(out) / MANIFEST) as tmp:
        tmp.write_text(json.dumps(found, indent=1, sort_keys=True) + "\n")
    return found


def read_manifest(path: str | Path) -> dict:
    found = load_json(Path(path), max_bytes=MAX_MANIFEST_BYTES, error=WeightsError)
    ok = (
        isinstance(found, dict)
        and found.get("format") == FORMAT
        and isinstance(found.get("files"), dict)
        and all(isinstance(v, str) and len(v) == 64 for v in found["files"].values())
    )
    if not ok:
        raise WeightsError(f"{path}: not a weights manifest (format {FORMAT})")
    return found


def fetch(source: str, manifest_path: str | Path, out: str | Path, progress: bool = True) -> Path:
    """Verify the archive at ``source`` against the committed manifest and unpack it as
    ``out``; the manifest is copied in beside the checkpoints."""
    from basic_shapes import release

    found = read_manifest(manifest_path)
    release.fetch_files(
        source,
        found["files"],
        out,
        f"the weights archive of {manifest_path}",
        progress=progress,
    )
    with atomic_path(Path(out) / MANIFEST) as tmp:
        tmp.write_text(json.dumps(found, indent=1, sort_keys=True) + "\n")
    return Path(out)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--out",
        required=True,
        help="the `benchmark reproduce --out` folder: packed from, or fetched into (new)",
    )
    what = parser.add_mutually_exclusive_group(required=True)
    what.add_argument(
        "--pack",
        metavar="ARCHIVE",
        help="write the folder's checkpoints as ARCHIVE (.tar) and their hashes as "
        f"OUT/{MANIFEST} (commit it with the table)",
    )
    what.add_argument(
        "--from",
        dest="source",
        metavar="PATH_OR_URL",
        help="fetch a weights archive, verify every file against --manifest, unpack into OUT",
    )
    parser.add_argument(
        "--manifest", help=f"with --from: the committed {MANIFEST} the archive must match"
    )
    add_quiet_flag(parser)


def run(args: argparse.Namespace) -> int:
    if args.source:
        if not args.manifest:
            raise WeightsError("--from needs --manifest (the committed weights.json)")
        fetch(args.source, args.manifest, args.out, progress=not args.quiet)
        found = read_manifest(Path(args.out) / MANIFEST)
        print(
            f"{args.out}: {len(found['files']) // len(FILES)} runs' weights verified; "
            f"rebuild their results with `benchmark reproduce --preset P --data D "
            f"--out {args.out}` (evaluation only)"
        )
        return 0
    if args.manifest:
        raise WeightsError("--manifest goes with --from")
    found = pack(args.out, args.pack)
    print(
        f"{args.pack}: {len(found['files']) // len(FILES)} runs, sha256 "
        f"{found['archive_sha256']}; manifest {Path(args.out) / MANIFEST}"
    )
    return 0
