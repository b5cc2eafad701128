"""A Dask client for the toolkit's batch jobs: a local cluster by default, or an existing one."""

from __future__ import annotations

import contextlib
import logging
import os
import socket
import struct
from urllib.parse import urlsplit

CONNECT_TIMEOUT_S = 3.0
MAX_HANDSHAKE_BYTES = 1 << 16


class SchedulerError(ConnectionError):
    """``--scheduler`` does not point at a reachable Dask scheduler (an OSError, like Dask's own
    connection errors, so callers that handle those handle this too)."""


def check_scheduler(address: str, timeout: float = CONNECT_TIMEOUT_S) -> None:
    """Refuse, within ``timeout`` seconds, an address that is not a Dask scheduler.

    A Dask server speaks first: on accept it sends its handshake, an 8-byte little-endian
    length and a small msgpack frame naming its pickle protocol. Distributed's own client
    trusts that length, so an HTTP server (which waits for a request) hangs it, and another
    service's banner read as a length asks for exabytes. Here the first bytes are checked
    by hand before Dask ever sees the address. Only tcp:// (or host:port) is probed; other
    schemes (tls://, ucx://) are handed to Dask as they are.
    """
    url = urlsplit(address if "://" in address else f"tcp://{address}")
    if url.scheme != "tcp":
        return
    try:
        host, port = url.hostname, url.port
    except ValueError:
        host = port = None
    if not host or not port:
        raise SchedulerError(f"--scheduler {address!r}: expected tcp://host:port")
    try:
        with socket.create_connection((host, port), timeout=timeout) as sock:
            sock.settimeout(timeout)
            head = _read(sock, 8)
            (size,) = struct.unpack("<Q", head)
            if not 0 < size <= MAX_HANDSHAKE_BYTES:
                raise SchedulerError(f"--scheduler {address}: not a Dask scheduler (it answered "
                                     f"{head!r}, not a Dask handshake)")
            if b"pickle-protocol" not in _read(sock, size):
                raise SchedulerError(f"--scheduler {address}: not a Dask scheduler (its first "
                                     f"message is not a Dask handshake)")
    except SchedulerError:
        raise
    except TimeoutError:
        raise SchedulerError(f"--scheduler {address}: not a Dask scheduler (no Dask handshake "
                             f"within {timeout:g} s)") from None
    except OSError as exc:
        raise SchedulerError(f"--scheduler {address}: cannot connect "
                             f"({exc.strerror or exc.__class__.__name__})") from None


def _read(sock: socket.socket, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = sock.recv(n - len(data))
        if not chunk:
            raise SchedulerError("the server closed the connection before a Dask handshake")
        data += chunk
    return data


@contextlib.contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None):
    """Yield a ``distributed.Client``.

    Local clusters run one single-threaded worker *process* per core (default ``os.cpu_count()``)
    because Blender and the Embree/numpy kernels each want a whole core and Blender keeps one
    state per process. ``scheduler`` ("tcp://host:8786") connects to a running cluster instead,
    after ``check_scheduler`` made sure it is one. ``workers=0`` runs one worker thread in this
    process (debugging, profiling).

    Dask starts local workers with MALLOC_TRIM_THRESHOLD_=65536, which freezes glibc's mmap
    threshold at 128 KiB: every large numpy temporary is then mmapped and page-faulted afresh
    (the radar simulator ran 2.4x slower per object). Local workers here keep glibc's default.
    Worker logs are silenced below CRITICAL: a task's error reaches the user once, as the
    one-line error of the command, not also as a block of Dask log lines.
    """
    import dask
    from distributed import Client, LocalCluster

    if not scheduler and workers is not None and (isinstance(workers, bool) or workers < 0):
        raise ValueError(f"--workers must be >= 0 (0 = in this process), got {workers}")
    with dask.config.set({"distributed.worker.daemon": False,
                          "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}):
        if scheduler:
            check_scheduler(scheduler)
            with Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S * 2:g}s") as client:
                yield client
            return
        in_process = workers == 0  # one thread in this process: debuggers and profilers see it
        n = 1 if in_process else workers or os.cpu_count() or 1
        with LocalCluster(n_workers=n, threads_per_worker=1, processes=not in_process,
                          dashboard_address=":0", silence_logs=logging.CRITICAL) as cluster, \
                Client(cluster) as client:
            yield client
