"""Release archives: a built dataset version (or any set of files with known hashes, such as
the baselines' trained weights) as one file, fetched and verified without Blender.

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
TIMEOUT_S = 60


class ReleaseError(ShardError):
    """An archive that cannot be fetched, is not the release it claims, or is corrupted."""


def pack(directory: str | os.PathLike, manifest: dict, archive: str | os.PathLike) -> Path:
    """Write ``directory`` (already checked against ``manifest``) as a release archive."""
    names = [CONFIG_FILE] + [s["name"] for s in manifest["shards"]]
    return pack_files(directory, names, archive, {MANIFEST_FILE: dumps(manifest).encode()})


def fetch(source: str, manifest: dict, directory: str | os.PathLike, progress: bool = True) -> Path:
    """Download (or copy) the archive at ``source``, verify it against ``manifest`` and
    unpack it as ``directory``, which must not hold a dataset yet."""
    expected = {s["name"]: s["sha256"] for s in manifest["shards"]}
    what = f"a release archive of {manifest['version']}"

    def check(staging: Path) -> None:
        config = load_json(staging / CONFIG_FILE, max_bytes=1 << 16, error=ReleaseError)
        if config != manifest.get("config"):
            raise ReleaseError(
                f"{source}: {CONFIG_FILE} is not the generator config of "
                f"{manifest['version']} ({json.dumps(config)[:80]})"
            )

    return fetch_files(
        source,
        {**expected, CONFIG_FILE: None},
        directory,
        what,
        ignored={MANIFEST_FILE},
        check=check,
        progress=progress,
    )


# --- any set of files with known hashes (datasets; the baselines' trained weights) -----------
SAFE_NAME = re.compile(r"[A-Za-z0-9_.-]+(/[A-Za-z0-9_.-]+)*")


def pack_files(
    directory: str | os.PathLike,
    names: list[str],
    archive: str | os.PathLike,
    extra: dict[str, bytes] | None = None,
) -> Path:
    """An uncompressed tar of ``directory``'s files ``names`` (paths relative to it) and the
    in-memory files ``extra``, written atomically; the same files give the same bytes."""
    directory, archive = Path(directory), Path(archive)
    for name in names:
        if not (directory / name).is_file():
            raise ReleaseError(f"{directory}: no {name}; nothing to pack")
    with atomic_path(archive) as tmp:
        with tarfile.open(tmp, "w", format=tarfile.PAX_FORMAT) as tar:
            for name, data in (extra or {}).items():
                info = _plain(tarfile.TarInfo(name))
                info.size = len(data)
                tar.addfile(info, io.BytesIO(data))
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


def fetch_files(
    source: str,
    expected: dict[str, str | None],
    directory: str | os.PathLike,
    what: str,
    *,
    ignored: set[str] = frozenset(),
    check=None,
    progress: bool = True,
) -> Path:
    """Download (or copy) the archive at ``source`` and unpack it as ``directory`` (new or
    empty) if it holds exactly the files ``expected`` (relative names -> sha256, None: checked
    by ``check(staging)`` instead) besides ``ignored`` ones, each with its hash; nothing is
    left behind otherwise. ``what`` names the archive in errors."""
    bad = [n for n in expected if not SAFE_NAME.fullmatch(n) or ".." in n.split("/")]
    if bad:
        raise ReleaseError(f"{source}: unsafe file name {bad[0]!r} in the expected files")
    directory = Path(directory)
    if directory.exists() and any(directory.iterdir()):
        raise ReleaseError(f"{directory}: not empty; fetch into a new directory")
    directory.parent.mkdir(parents=True, exist_ok=True)
    download = directory.parent / f".{directory.name}.download"
    staging = directory.parent / f".{directory.name}.unpack"
    shutil.rmtree(staging, ignore_errors=True)
    try:
        archive = _download(source, download, progress)
        _unpack(archive, source, expected, ignored, what, staging)
        if check is not None:
            check(staging)
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


def _unpack(
    archive: Path, source: str, expected: dict, ignored: set, what: str, staging: Path
) -> None:
    try:
        with tarfile.open(archive, "r:") as tar:
            members = tar.getmembers()
            names = [m.name for m in members]
            for m in members:
                if not m.isreg() or (m.name not in expected and m.name not in ignored):
                    raise ReleaseError(f"{source}: unexpected member {m.name!r}; not {what}")
            missing = sorted(set(expected) - set(names))
            if missing or len(set(names)) != len(names):
                raise ReleaseError(f"{source}: not {what} (missing {missing[:3]})")
            staging.mkdir(parents=True)
            for m in members:
                if m.name in ignored:
                    continue
                (staging / m.name).parent.mkdir(parents=True, exist_ok=True)
                with tar.extractfile(m) as src, open(staging / m.name, "wb") as dst:
                    shutil.copyfileobj(src, dst, 1 << 20)
    except (tarfile.TarError, EOFError) as exc:
        raise ReleaseError(f"{source}: not a readable tar archive ({exc})") from None
    for name, sha in expected.items():
        if sha is not None and file_sha256(staging / name) != sha:
            raise ReleaseError(
                f"{source}: {name} does not match the sha256 of {what} (corrupted or another build)"
            )
