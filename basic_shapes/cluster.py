"""The toolkit's one batch runner (``run_tasks``) and its Dask client: a local cluster by
default, an existing one with ``--scheduler``, or one worker thread in this process (or, for
Blender, the calling thread itself: ``batch_client``)."""

from __future__ import annotations

import contextlib
import logging
import math
import os
import signal
import socket
import struct
import threading
import time
from urllib.parse import urlsplit

CONNECT_TIMEOUT_S = 3.0
MAX_HANDSHAKE_BYTES = 1 << 16
NO_WORKER_TIMEOUT_S = 60.0
"""A batch job fails once its cluster has had no worker this long while tasks wait
(docs/CLI.md); ``NO_WORKER_ENV`` overrides it (tests, clusters whose workers start slowly)."""
NO_WORKER_ENV = "BASIC_SHAPES_NO_WORKER_TIMEOUT_S"


class SchedulerError(ConnectionError):
    """``--scheduler`` does not point at a reachable Dask scheduler (an OSError, like Dask's own
    connection errors, so callers that handle those handle this too)."""


class NoWorkersError(SchedulerError):
    """The cluster had no worker for ``no_worker_timeout()`` seconds while tasks waited."""


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
                raise SchedulerError(
                    f"--scheduler {address}: not a Dask scheduler (it answered "
                    f"{head!r}, not a Dask handshake)"
                )
            if b"pickle-protocol" not in _read(sock, size):
                raise SchedulerError(
                    f"--scheduler {address}: not a Dask scheduler (its first "
                    f"message is not a Dask handshake)"
                )
    except SchedulerError:
        raise
    except TimeoutError:
        raise SchedulerError(
            f"--scheduler {address}: not a Dask scheduler (no Dask handshake within {timeout:g} s)"
        ) from None
    except OSError as exc:
        raise SchedulerError(
            f"--scheduler {address}: cannot connect ({exc.strerror or exc.__class__.__name__})"
        ) from None


def _read(sock: socket.socket, n: int) -> bytes:
    data = b""
    while len(data) < n:
        chunk = sock.recv(n - len(data))
        if not chunk:
            raise SchedulerError("the server closed the connection before a Dask handshake")
        data += chunk
    return data


def no_worker_timeout() -> float:
    """``NO_WORKER_TIMEOUT_S``, or the seconds in the environment variable ``NO_WORKER_ENV``."""
    text = os.environ.get(NO_WORKER_ENV, "")
    if not text:
        return NO_WORKER_TIMEOUT_S
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value > 0):
        raise ValueError(f"{NO_WORKER_ENV}={text!r}: expected a number of seconds > 0")
    return value


def finished(client, futures):
    """Iterate ``futures`` (a ``distributed.as_completed``, which may grow meanwhile) as they
    finish, but raise ``NoWorkersError`` once the cluster has had no worker for
    ``no_worker_timeout()`` seconds while tasks wait.

    Dask waits for workers forever and says nothing: a job on a scheduler without workers sat
    at 0% for 11.5 minutes. A finished task counts as a sign of life, so only the time without
    any worker counts. Finished work is kept (shards, labelled objects): a rerun resumes.
    A Ctrl-C is not lost either (``_noted_sigint``).
    """
    timeout = no_worker_timeout()
    with _noted_sigint() as interrupted:
        alive = checked = time.monotonic()
        while not futures.is_empty():
            if interrupted():
                raise KeyboardInterrupt
            if futures.has_ready():
                yield next(futures)
                alive = time.monotonic()
                continue
            now = time.monotonic()
            if now - checked >= 1.0:
                checked = now
                if client.nthreads():
                    alive = now
                elif now - alive >= timeout:
                    where = (
                        "the local Dask cluster"
                        if client.cluster is not None
                        else f"--scheduler {client.scheduler.address}"
                    )
                    raise NoWorkersError(
                        f"{where}: no Dask worker for {timeout:g} s with "
                        f"tasks waiting; start workers (dask worker ADDRESS) "
                        f"and rerun: finished work is kept"
                    )
            time.sleep(0.05)


@contextlib.contextmanager
def _noted_sigint():
    """Yield a test for "Ctrl-C was pressed"; the loop then raises KeyboardInterrupt itself.

    Python drops a KeyboardInterrupt raised in a destructor or a weakref callback (Dask and
    h5py run many: a job went on after printing "Exception ignored ... KeyboardInterrupt"), so
    the first SIGINT is only noted, and raised at the loop's next turn (within 50 ms while it
    waits); a second one raises at once. Main thread only, like Python's signal handlers."""
    noted = []
    if threading.current_thread() is not threading.main_thread():
        yield lambda: False
        return

    def handler(signum, frame):
        noted.append(signum)
        if len(noted) > 1:
            raise KeyboardInterrupt

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield lambda: bool(noted)
    finally:  # None: a handler set outside Python
        signal.signal(signal.SIGINT, signal.default_int_handler if previous is None else previous)


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
    one-line error of the command, not also as a block of Dask log lines. Ctrl-C reaches the
    whole process group, but only this process answers it (``<tool>: interrupted``) and stops
    its workers: local worker processes start with SIGINT blocked (``_hold_sigint``) instead of
    each printing a traceback; a Ctrl-C during the start is delivered once the cluster runs.
    Iterate results with ``finished``.
    """
    if not scheduler and workers is not None and (isinstance(workers, bool) or workers < 0):
        raise ValueError(f"--workers must be >= 0 (0 = in this process), got {workers}")
    if scheduler:
        check_scheduler(scheduler)  # before importing Dask (seconds): a refusal is immediate
    import dask
    from distributed import Client, LocalCluster

    with dask.config.set(
        {
            "distributed.worker.daemon": False,
            "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
        }
    ):
        if scheduler:
            with Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S * 2:g}s") as client:
                yield client
            return
        in_process = workers == 0  # one thread in this process: debuggers and profilers see it
        n = 1 if in_process else workers or os.cpu_count() or 1
        release = (lambda: None) if in_process else _hold_sigint()
        try:
            cluster = LocalCluster(
                n_workers=n,
                threads_per_worker=1,
                processes=not in_process,
                dashboard_address=":0",
                silence_logs=logging.CRITICAL,
            )
        except BaseException:
            release()
            raise
        with cluster:
            release()  # a Ctrl-C of the start-up arrives here, and the cluster closes cleanly
            with Client(cluster) as client:
                yield client


@contextlib.contextmanager
def batch_client(workers: int | None = None, scheduler: str | None = None, *, main_thread=False):
    """``dask_client``, except that with ``main_thread`` ``workers=0`` yields no client at all:
    ``run_tasks`` then runs each task in the calling thread. Blender needs it: once bpy has run
    on any other thread, the process segfaults at exit (bpy 5.0), and Dask's in-process worker
    is another thread."""
    if main_thread and not scheduler and workers == 0 and not isinstance(workers, bool):
        yield None
        return
    with dask_client(workers, scheduler) as client:
        yield client


def worker_threads(client) -> int:
    """The worker threads a job runs on (1 for ``batch_client``'s main-thread mode)."""
    return 1 if client is None else max(1, sum(client.nthreads().values()))


class TaskError(Exception):
    """A task failed: ``tag`` is what the caller submitted it with, ``error`` what it raised."""

    def __init__(self, tag, error: BaseException):
        super().__init__(str(error))
        self.tag, self.error = tag, error


def run_tasks(client, fn, tasks, window_per_thread: int = 4):
    """Yield ``(tag, fn(*args))`` for each ``(tag, args)`` of the iterable ``tasks``, as they
    finish. At most ``window_per_thread`` tasks per worker thread are submitted at a time, so
    a lazy ``tasks`` (one that reads its meshes as it goes) never holds the whole job in
    memory; ``finished`` watches for a cluster without workers and for Ctrl-C. A failed task
    raises ``TaskError`` naming its tag. Generation and labelling both run through this;
    ``client=None`` (``batch_client``'s main-thread mode) runs each task here, in order."""
    if client is None:
        for tag, args in tasks:
            try:
                result = fn(*args)
            except Exception as exc:
                raise TaskError(tag, exc) from exc
            yield tag, result
        return
    from distributed import as_completed

    tasks = iter(tasks)
    running, owner = as_completed(), {}

    def submit_next() -> None:
        item = next(tasks, None)
        if item is not None:
            tag, args = item
            future = client.submit(fn, *args, pure=False)
            owner[future.key] = tag
            running.add(future)

    for _ in range(window_per_thread * max(1, sum(client.nthreads().values()))):
        submit_next()
    for future in finished(client, running):
        tag = owner.pop(future.key)
        try:
            result = future.result()
        except Exception as exc:
            raise TaskError(tag, exc) from exc
        future.release()
        yield tag, result
        submit_next()


def _hold_sigint():
    """Block SIGINT in this thread until the returned function is called.

    Threads and processes started meanwhile inherit the blocked signal: the cluster's loop
    thread, and the worker processes it spawns (also later ones). Multiprocessing's resource
    tracker is started first, because starting it unblocks SIGINT in the thread that does.
    """
    from multiprocessing import resource_tracker

    resource_tracker.ensure_running()
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    return lambda: signal.pthread_sigmask(signal.SIG_SETMASK, mask)
