"""Infrastructure the four packages share: atomic writes, one-line errors, the CLI error
boundary, the machine's description, bounded JSON and the hardened HDF5 opener (docs/CLI.md).

Every file a user hands the toolkit (shards, predictions, results, entries, configs) is
untrusted: it is read through ``load_json`` or ``open_hdf5``, which refuse anything whose
declared size is not backed by the file's own bytes *before* reading it, so a small hostile
file cannot cost more memory or time than its own size.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import json
import math
import os
import platform
import re
import stat
import sys
from pathlib import Path

import numpy as np

DEBUG_ENV = "BASIC_SHAPES_DEBUG"


class FlagError(ValueError):
    """Flags that contradict each other (an output that is an input): exit status 2, before
    any work, like the parser's own refusals."""


class InputError(ValueError):
    """An input file is unreadable, malformed or hostile (one line naming the file)."""


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a temporary path; on success fsync it and rename it onto ``path``. A full disk
    (or quota, or file size limit) is raised as an ``OSError`` naming ``path``."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.unlink(missing_ok=True)
    try:
        yield tmp
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
        fsync_dir(path.parent)
    except (OSError, RuntimeError) as exc:
        code = _disk_full(exc)
        if code is None:
            raise
        raise OSError(code, os.strerror(code), str(path)) from exc
    finally:
        tmp.unlink(missing_ok=True)


def write_json(path: str | os.PathLike, payload) -> None:
    """``payload`` as indented JSON at ``path`` (parent folders made), written atomically: the
    one way measurement scripts write their results."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(payload, indent=1) + "\n")


def save_png(fig, out: str | os.PathLike, dpi: int = 110) -> None:
    """Write a matplotlib figure as PNG atomically (a killed run leaves the old picture or
    none, never half of one) and close it; no software tag, so same input, same bytes."""
    import matplotlib.pyplot as plt

    Path(out).parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out) as tmp:
        fig.savefig(tmp, format="png", dpi=dpi, metadata={"Software": None})
    plt.close(fig)


_DISK_FULL = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)
FREE_MARGIN = 64 << 20  # bytes kept free beyond a write's estimate (HDF5 metadata, labels)


def require_free_space(path: str | os.PathLike, nbytes: int) -> None:
    """Refuse (``OSError`` ENOSPC naming ``path``) a write of about ``nbytes`` that the disk
    cannot hold, before it starts: HDF5 that runs out of space mid-write can crash the
    process on close (h5py issues 914, 2160) instead of raising."""
    import shutil

    free = shutil.disk_usage(Path(path).parent).free
    if free < nbytes + FREE_MARGIN:
        raise OSError(
            errno.ENOSPC,
            f"No space left on device (about "
            f"{(nbytes + FREE_MARGIN) >> 20} MiB needed, {free >> 20} MiB free)",
            str(path),
        )


def _disk_full(exc: BaseException | None) -> int | None:
    """The errno of a full disk, quota or file size limit behind ``exc``, else None. The write
    that hits it often names no file (h5py's error also spans lines and names the temporary
    file, and closing the file then raises a RuntimeError), so ``atomic_path`` names ``path``."""
    for _ in range(8):  # exc and what it was raised while handling
        if exc is None:
            return None
        code = getattr(exc, "errno", None)
        found = re.search(r"errno = (\d+)", str(exc)) if code is None else None
        code = int(found.group(1)) if found else code
        if code in _DISK_FULL:
            return code
        exc = exc.__context__
    return None


def fsync_dir(directory: str | os.PathLike) -> None:
    """Make a rename in ``directory`` durable."""
    dir_fd = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def utc_timestamp() -> str:
    """Now, in the one timestamp format of results, entries and tables: 2026-11-23T15:56:13Z."""
    import datetime

    return datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def hardware(threads: int | None = None) -> dict:
    """The one description of the machine a speed was measured on (models and physics alike).

    CPU model, cores, the threads the timed code ran with (``threads``; by default torch's
    when torch is loaded, else every core the process may use, as numpy's BLAS and Embree
    do), the 1-minute load average when timing (other work on the CPU
    slows everything), and the GPU when torch is loaded and sees one. ``text`` is the line
    shown in tables and on the board.
    """
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as fh:
            cpu = next(
                line.split(":", 1)[1].strip() for line in fh if line.startswith("model name")
            )
    except (OSError, StopIteration):
        pass
    torch = sys.modules.get("torch")
    if threads is None:
        threads = torch.get_num_threads() if torch is not None else _usable_cores()
    gpu = torch.cuda.get_device_name(0) if torch is not None and torch.cuda.is_available() else None
    try:
        load = round(os.getloadavg()[0], 2)
    except OSError:
        load = None
    text = f"cpu: {cpu} ({os.cpu_count()} cores)"
    text += f", {threads} thread(s)"
    text += f", load {load:.2f}" if load is not None else ""
    text += f"; gpu: {gpu}" if gpu else ""
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "threads": threads,
        "load_avg_1m": load,
        "gpu": gpu,
        "text": text,
    }


def _usable_cores() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:
        return os.cpu_count() or 1


# --- one-line errors and the CLI boundary ----------------------------------------------------


def warn(text: str) -> None:
    """One ``warning:`` line on stderr (stdout is kept for results)."""
    print(f"warning: {text}", file=sys.stderr, flush=True)


def one_line(exc: BaseException) -> str:
    """An exception as one line: ``file: problem`` for OS errors, else its first message line."""
    if isinstance(exc, OSError) and exc.strerror:
        where = exc.filename if exc.filename is not None else ""
        problem = (exc.strerror.strip().splitlines() or [exc.strerror])[0]
        if exc.errno and "errno = " in exc.strerror:  # h5py's page of HDF5 details
            problem = os.strerror(exc.errno)
        return f"{where}: {problem}" if where != "" else problem
    try:
        lines = str(exc).strip().splitlines()
    except Exception:
        lines = []
    return lines[0] if lines else exc.__class__.__name__


def _is_expected(exc: BaseException) -> bool:
    """Errors of the input or the environment (not bugs): they get a plain one-line message."""
    return isinstance(exc, (ValueError, OSError, MemoryError)) or type(exc).__name__ in (
        "KilledWorker",
        "CancelledError",
        "FutureCancelledError",
    )


def describe(exc: BaseException) -> str:
    """The one line a user sees for ``exc``."""
    if isinstance(exc, MemoryError):
        return f"out of memory ({one_line(exc)})"
    if type(exc).__name__ == "KilledWorker":
        return (
            f"a Dask worker died while running task {getattr(exc, 'task', '?')!r} (out "
            f"of memory or crashed); see the worker logs"
        )
    if _is_expected(exc):
        return one_line(exc)
    return (
        f"internal error: {exc.__class__.__name__}: {one_line(exc)} "
        f"(rerun with --debug for the traceback)"
    )


def debug_requested(argv: list[str]) -> bool:
    return "--debug" in argv or os.environ.get(DEBUG_ENV, "") not in ("", "0")


def cli_boundary(tool: str, body, argv: list[str] | None = None):
    """Run ``body(argv)`` behind the single top-level error boundary of the four CLIs.

    Any exception becomes ``<tool> <command>: error: <one line>`` on stderr and exit status 1;
    argparse refusals (flags) exit with 2 (``ArgumentParser``). ``--debug`` anywhere on the
    command line (removed before parsing) or ``BASIC_SHAPES_DEBUG=1`` shows tracebacks.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = debug_requested(argv)
    argv = [a for a in argv if a != "--debug"]
    command = next((a for a in argv if not a.startswith("-")), None)
    prefix = f"{tool} {command}" if command else tool
    try:
        return body(argv)
    except SystemExit as exc:
        if debug or exc.code is None or isinstance(exc.code, int):
            raise
        msg = _unprefixed(one_line(Exception(str(exc.code))), tool)
        raise SystemExit(f"{prefix}: error: {msg}") from None
    except FlagError as exc:
        if debug:
            raise
        print(f"{prefix}: error: {one_line(exc)}", file=sys.stderr)
        raise SystemExit(2) from None
    except KeyboardInterrupt:
        if debug:
            raise
        print(f"{tool}: interrupted", file=sys.stderr)
        raise SystemExit(130) from None
    except BaseException as exc:
        if debug:
            raise
        raise SystemExit(f"{prefix}: error: {describe(exc)}") from None


def _unprefixed(message: str, tool: str) -> str:
    """``message`` without a leading ``<tool>[ <command>]:`` and ``error:`` (added once, above)."""
    head, sep, rest = message.partition(": ")
    command = head.removeprefix(f"{tool} ")
    if sep and (head == tool or (command != head and " " not in command)):
        message = rest
    return message.removeprefix("error: ")


class ArgumentParser(argparse.ArgumentParser):
    """argparse with one-line refusals (``prog: error: ...``, exit status 2)."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def separate_outputs(outputs: dict, inputs: dict) -> None:
    """Refuse (``FlagError``) an output flag whose path is an input's, lies inside an input
    directory (the dataset) or holds an input (a folder that is replaced), or is another
    output's; ``None`` values are ignored. Paths are compared after resolving symlinks."""

    def real(path) -> str:
        return os.path.realpath(os.fspath(path))

    def nested(a: str, b: str) -> bool:
        return a == b or a.startswith(b.rstrip(os.sep) + os.sep)

    seen: dict[str, str] = {}
    for flag, path in outputs.items():
        if path is None:
            continue
        out = real(path)
        if out in seen:
            raise FlagError(f"{flag} and {seen[out]} name the same path ({path})")
        seen[out] = flag
        for in_flag, in_path in inputs.items():
            if in_path is not None and (nested(out, real(in_path)) or nested(real(in_path), out)):
                raise FlagError(
                    f"{flag} {path} would overwrite the input {in_flag} {in_path}; "
                    f"write it elsewhere"
                )


def add_debug_flag(parser: argparse.ArgumentParser) -> None:
    """``--version`` (the toolkit's) and ``--debug`` (documented here; ``cli_boundary`` removes
    it before parsing, wherever it is), on every tool."""
    from basic_shapes import __version__

    parser.add_argument(
        "--version",
        action="version",
        version=f"%(prog)s {__version__}",
        help="print the toolkit version and exit",
    )
    parser.add_argument(
        "--debug", action="store_true", help=f"show Python tracebacks (also {DEBUG_ENV}=1)"
    )


def add_cluster_flags(parser: argparse.ArgumentParser, what: str = "worker processes") -> None:
    """``--workers N`` (0 = in this process) or ``--scheduler ADDR``, never both (docs/CLI.md)."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument(
        "--workers",
        type=number(int, minimum=0, maximum=1024),
        default=None,
        help=f"local {what} (default: one per core; 0 = in this process, "
        f"for debugging: the same bytes)",
    )
    group.add_argument(
        "--scheduler",
        default=None,
        metavar="ADDR",
        help="address of a running Dask scheduler (tcp://host:8786) instead",
    )


def add_quiet_flag(parser: argparse.ArgumentParser) -> None:
    """``--quiet``: no progress bars or informational lines; results and errors still print."""
    parser.add_argument(
        "--quiet",
        action="store_true",
        help="no progress bars or progress lines (results and errors still print)",
    )


def number(kind=float, *, minimum=None, maximum=None, above=None, integer_ok=True):
    """An argparse ``type`` for finite numbers in a range, naming the bound it breaks."""

    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            what = "an integer" if kind is int else "a number"
            raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{text!r} is not a finite number")
        if minimum is not None and value < minimum:
            raise argparse.ArgumentTypeError(f"{text!r} must be >= {minimum:g}")
        if above is not None and value <= above:
            raise argparse.ArgumentTypeError(f"{text!r} must be > {above:g}")
        if maximum is not None and value > maximum:
            raise argparse.ArgumentTypeError(f"{text!r} must be <= {maximum:g}")
        return value

    parse.__name__ = kind.__name__
    return parse


# --- files and bounded JSON --------------------------------------------------------------------


def regular_file(path: str | os.PathLike, error=InputError) -> os.stat_result:
    """``stat`` of ``path``, refusing anything but a regular file (a FIFO would hang a read)."""
    try:
        st = os.stat(path)
    except OSError as exc:
        raise error(f"{path}: {exc.strerror or exc.__class__.__name__}") from None
    if not stat.S_ISREG(st.st_mode):
        raise error(f"{path}: not a regular file")
    return st


JSON_MAX_BYTES = 4 << 20
JSON_MAX_DEPTH = 32
_JSON_STRING = re.compile(rb'"(?:[^"\\]|\\.)*"', re.DOTALL)


def json_depth(raw: bytes) -> int:
    """Nesting depth of JSON text, without recursion (strings removed, brackets counted)."""
    arr = np.frombuffer(_JSON_STRING.sub(b'""', raw), np.uint8)
    step = np.isin(arr, (ord("["), ord("{"))).astype(np.int64) - np.isin(
        arr, (ord("]"), ord("}"))
    ).astype(np.int64)
    return int(np.cumsum(step).max(initial=0))


def _finite_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"number {text[:20]} is out of range")
    return value


def _no_constant(name: str):
    raise ValueError(f"{name} is not allowed")


def load_json(
    source: str | bytes | os.PathLike,
    *,
    what: str | None = None,
    max_bytes: int = JSON_MAX_BYTES,
    max_depth: int = JSON_MAX_DEPTH,
    error=InputError,
):
    """Parse JSON from a file path (``os.PathLike``) or from text/bytes, bounded.

    Refused with ``error`` naming ``what`` (default: the path): more than ``max_bytes``,
    nesting deeper than ``max_depth`` (checked before parsing, so no RecursionError),
    NaN/Infinity constants, numbers that overflow a float, integers of over 4300 digits.
    """
    if isinstance(source, os.PathLike):
        what = what or str(source)
        regular_file(source, error)
        try:
            with open(source, "rb") as fh:
                raw = fh.read(max_bytes + 1)
        except OSError as exc:
            raise error(f"{what}: cannot read ({one_line(exc)})") from None
    else:
        what = what or "JSON text"
        raw = source.encode() if isinstance(source, str) else bytes(source)
    if raw.startswith(b"\x89HDF\r\n\x1a\n"):  # the usual slip: two files' places swapped
        raise error(f"{what}: an HDF5 file, not JSON")
    if len(raw) > max_bytes:
        raise error(f"{what}: larger than the {max_bytes} bytes allowed")
    depth = json_depth(raw)
    if depth > max_depth:
        raise error(f"{what}: JSON nested {depth} deep, more than the {max_depth} allowed")
    try:
        return json.loads(
            raw.decode("utf-8"), parse_constant=_no_constant, parse_float=_finite_float
        )
    except (ValueError, RecursionError) as exc:
        raise error(f"{what}: not valid JSON ({one_line(exc)})") from None


# --- the hardened HDF5 opener ----------------------------------------------------------------

MAX_HDF5_OBJECTS = 4096
# deflate cannot expand more than ~1032x; anything beyond is not a real compressed dataset
MAX_COMPRESSION = 1100


def open_hdf5(path: str | os.PathLike, error=InputError, what: str = "HDF5 file"):
    """Open an untrusted HDF5 file read-only after checking everything in it is plain.

    Refused before any data is read: non-regular files (FIFOs, devices), links other than
    hard links (external or soft), virtual datasets, external storage (``dset.external``,
    which reads other files of this machine), layouts other than contiguous / chunked /
    compact, unknown filters, named datatypes, and any dataset or attribute whose declared
    size is not backed by stored bytes (a 6 KB file declaring 1e9 rows) or whose stored
    bytes exceed the file's size.
    """
    import h5py

    size = regular_file(path, error).st_size
    try:
        f = h5py.File(path, "r")
    except (OSError, ValueError) as exc:
        raise error(f"{path}: not a readable {what} ({one_line(exc)})") from None
    try:
        _HDF5Check(path, size, error).group(f, "")
    except (KeyError, RuntimeError, OSError) as exc:  # h5py on a corrupted header
        f.close()
        raise error(f"{path}: not a readable {what} ({one_line(exc)})") from None
    except BaseException:
        f.close()
        raise
    return f


class _HDF5Check:
    def __init__(self, path, file_size: int, error):
        self.path, self.file_size, self.error = path, file_size, error
        self.count, self.seen = 0, set()

    def fail(self, where: str, problem: str):
        raise self.error(f"{self.path}: {where or '/'} {problem}")

    def group(self, g, prefix: str) -> None:
        import h5py

        self.attrs(g, prefix)
        for name in g:
            where = f"{prefix}/{name}"
            self.count += 1
            if self.count > MAX_HDF5_OBJECTS:
                self.fail("", f"holds more than {MAX_HDF5_OBJECTS} objects")
            link = g.get(name, getlink=True)
            if not isinstance(link, h5py.HardLink):
                self.fail(
                    where, f"is a link ({type(link).__name__}); only plain datasets are allowed"
                )
            obj = g[name]
            addr = h5py.h5o.get_info(obj.id).addr
            if addr in self.seen:
                self.fail(where, "is linked twice (only a tree of plain objects is allowed)")
            self.seen.add(addr)
            if isinstance(obj, h5py.Group):
                self.group(obj, where)
            elif isinstance(obj, h5py.Dataset):
                self.dataset(obj, where)
            else:
                self.fail(where, f"is a {type(obj).__name__}; only groups and datasets are allowed")

    def declared(self, shape, type_id) -> int:
        n = math.prod(int(s) for s in shape) if shape else 1
        return n * type_id.get_size()

    def attrs(self, obj, where: str) -> None:
        import h5py

        for name in obj.attrs:
            a = h5py.h5a.open(obj.id, name.encode())
            need = self.declared(a.shape, a.get_type())
            stored = a.get_storage_size()
            if stored > self.file_size or need > stored:
                self.fail(where, f"attribute {name!r} declares {need} bytes but stores {stored}")

    def dataset(self, d, where: str) -> None:
        from h5py import h5d, h5z

        self.attrs(d, where)
        if d.is_virtual:
            self.fail(where, "is a virtual dataset (reads other files)")
        plist = d.id.get_create_plist()
        if plist.get_external_count():
            self.fail(
                where,
                "uses external storage (reads other files); only data stored in "
                "the file is allowed",
            )
        layout = plist.get_layout()
        if layout not in (h5d.CONTIGUOUS, h5d.CHUNKED, h5d.COMPACT):
            self.fail(where, f"has an unsupported storage layout ({layout})")
        filters = [plist.get_filter(i)[0] for i in range(plist.get_nfilters())]
        if set(filters) - {h5z.FILTER_DEFLATE, h5z.FILTER_SHUFFLE, h5z.FILTER_FLETCHER32}:
            self.fail(where, f"uses an unsupported filter {filters}")
        need = self.declared(d.shape, d.id.get_type())
        stored = d.id.get_storage_size()
        compressed = h5z.FILTER_DEFLATE in filters
        if stored > self.file_size or need > stored * (MAX_COMPRESSION if compressed else 1):
            self.fail(
                where,
                f"declares {d.shape} ({need} bytes) but the file stores {stored} "
                f"bytes for it ({self.file_size} in all)",
            )


def require_dataset(f, name: str, kinds: str, ndim: int, error, path, tail: tuple = ()):
    """``f[name]`` if it is a dataset of dtype kind in ``kinds`` with ``ndim`` dims ending in
    ``tail``; else ``error`` naming the file and the dataset."""
    import h5py

    d = f.get(name)
    if not isinstance(d, h5py.Dataset):
        raise error(f"{path}: /{name} is missing or not a dataset")
    if d.dtype.kind not in kinds or d.ndim != ndim or tuple(d.shape[ndim - len(tail) :]) != tail:
        raise error(
            f"{path}: /{name} is {d.dtype}{d.shape}, expected kind {kinds!r} with "
            f"{ndim} dimension(s){' ending in ' + str(tail) if tail else ''}"
        )
    return d
