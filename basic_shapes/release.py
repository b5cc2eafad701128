"""Release archives: a built dataset version as one file, fetched and verified without Blender.

``pack`` writes ``dataset.json``, the manifest and the shards into an uncompressed tar (HDF5
shards of float arrays hardly compress; a plain tar streams and seeks). ``fetch`` takes a
path or an http(s)/file URL, downloads to a temporary file beside the target, and accepts
the archive only if every member is a regular file with an expected name and every shard's
sha256 is the one in the manifest committed with the toolkit (the archive's own manifest is
never trusted); it then unpacks into a temporary directory and renames it into place, so a
corrupted, foreign or interrupted download leaves nothing behind.
"""

from __future__ import annotations

import io
import json
import os
import re
import shutil
import tarfile
import urllib.parse
import urllib.request
from pathlib import Path

from basic_shapes.infra import atomic_path, load_json
from basic_shapes.manifest import dumps, file_sha256
from basic_shapes.shards import ShardError

CONFIG_FILE = "dataset.json"
MANIFEST_FILE = "manifest.json"
MEMBER = re.compile(r"(shard-\d{5}\.h5|dataset\.json|manifest\.json)")
TIMEOUT_S = 60


class ReleaseError(ShardError):
    """An archive that cannot be fetched, is not a release of the version, or is corrupted."""


def pack(directory: str | os.PathLike, manifest: dict, archive: str | os.PathLike) -> Path:
    """Write ``directory`` (already checked against ``manifest``) as a release archive."""
    directory, archive = Path(directory), Path(archive)
    names = [CONFIG_FILE] + [s["name"] for s in manifest["shards"]]
    for name in names:
        if not (directory / name).is_file():
            raise ReleaseError(f"{directory}: no {name}; build the version first")
    with atomic_path(archive) as tmp:
        with tarfile.open(tmp, "w", format=tarfile.PAX_FORMAT) as tar:
            info = tarfile.TarInfo(MANIFEST_FILE)
            text = dumps(manifest).encode()
            info.size = len(text)
            tar.addfile(info, io.BytesIO(text))
            for name in names:
                tar.add(directory / name, arcname=name, filter=_plain)
    return archive


def _plain(info: tarfile.TarInfo) -> tarfile.TarInfo:
    """Owner, group and time stripped: the same files give the same archive."""
    info.uid = info.gid = 0
    info.uname = info.gname = ""
    info.mtime = 0
    info.mode = 0o644
    return info


def fetch(source: str, manifest: dict, directory: str | os.PathLike, progress: bool = True) -> Path:
    """Download (or copy) the archive at ``source``, verify it against ``manifest`` and
    unpack it as ``directory``, which must not hold a dataset yet."""
    directory = Path(directory)
    if directory.exists() and any(directory.iterdir()):
        raise ReleaseError(f"{directory}: not empty; fetch into a new directory")
    directory.parent.mkdir(parents=True, exist_ok=True)
    download = directory.parent / f".{directory.name}.download"
    staging = directory.parent / f".{directory.name}.unpack"
    shutil.rmtree(staging, ignore_errors=True)
    try:
        archive = _download(source, download, progress)
        _unpack(archive, source, manifest, staging)
        if directory.exists():
            directory.rmdir()
        os.replace(staging, directory)
    finally:
        download.unlink(missing_ok=True)
        shutil.rmtree(staging, ignore_errors=True)
    return directory


def _download(source: str, target: Path, progress: bool) -> Path:
    scheme = urllib.parse.urlparse(source).scheme
    if scheme not in ("http", "https", "file"):
        path = Path(source)
        if not path.is_file():
            raise ReleaseError(f"{source}: no such archive file")
        return path
    from tqdm import tqdm

    try:
        with (
            urllib.request.urlopen(source, timeout=TIMEOUT_S) as response,
            open(target, "wb") as out,
        ):
            total = int(response.headers.get("Content-Length") or 0) or None
            with tqdm(
                total=total, unit="B", unit_scale=True, desc="fetch", disable=not progress
            ) as bar:
                for block in iter(lambda: response.read(1 << 20), b""):
                    out.write(block)
                    bar.update(len(block))
    except OSError as exc:  # URLError, HTTPError, timeouts and a full disk are all OSErrors
        raise ReleaseError(f"{source}: cannot download ({exc})") from None
    return target


def _unpack(archive: Path, source: str, manifest: dict, staging: Path) -> None:
    expected = {s["name"]: s["sha256"] for s in manifest["shards"]}
    try:
        with tarfile.open(archive, "r:") as tar:
            members = tar.getmembers()
            names = [m.name for m in members]
            for m in members:
                if not m.isreg() or not MEMBER.fullmatch(m.name):
                    raise ReleaseError(
                        f"{source}: unexpected member {m.name!r}; not a release "
                        f"archive of {manifest['version']}"
                    )
            missing = sorted((set(expected) | {CONFIG_FILE}) - set(names))
            extra = sorted({n for n in names if n.startswith("shard-")} - set(expected))
            if missing or extra or len(set(names)) != len(names):
                raise ReleaseError(
                    f"{source}: not a release archive of {manifest['version']} "
                    f"(missing {missing[:3]}, unexpected {extra[:3]})"
                )
            staging.mkdir(parents=True)
            for m in members:
                if m.name == MANIFEST_FILE:
                    continue
                with tar.extractfile(m) as src, open(staging / m.name, "wb") as dst:
                    shutil.copyfileobj(src, dst, 1 << 20)
    except (tarfile.TarError, EOFError) as exc:
        raise ReleaseError(f"{source}: not a readable tar archive ({exc})") from None
    for name, sha in expected.items():
        if file_sha256(staging / name) != sha:
            raise ReleaseError(
                f"{source}: {name} does not match the sha256 in the manifest of "
                f"{manifest['version']} (corrupted or another build)"
            )
    config = load_json(staging / CONFIG_FILE, max_bytes=1 << 16, error=ReleaseError)
    if config != manifest.get("config"):
        raise ReleaseError(
            f"{source}: {CONFIG_FILE} is not the generator config of "
            f"{manifest['version']} ({json.dumps(config)[:80]})"
        )
