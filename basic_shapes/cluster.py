"""A Dask client for the toolkit's batch jobs: a local cluster by default, or an existing one."""

from __future__ import annotations

import contextlib
import logging
import os


@contextlib.contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None):
    """Yield a ``distributed.Client``.

    Local clusters run one single-threaded worker *process* per core (default ``os.cpu_count()``)
    because Blender and the Embree/numpy kernels each want a whole core and Blender keeps one
    state per process. ``scheduler`` ("tcp://host:8786") connects to a running cluster instead.

    Dask starts local workers with MALLOC_TRIM_THRESHOLD_=65536, which freezes glibc's mmap
    threshold at 128 KiB: every large numpy temporary is then mmapped and page-faulted afresh
    (the radar simulator ran 2.4x slower per object). Local workers here keep glibc's default.
    """
    import dask
    from distributed import Client, LocalCluster

    with dask.config.set({"distributed.worker.daemon": False,
                          "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}):
        if scheduler:
            with Client(scheduler) as client:
                yield client
            return
        n = workers or os.cpu_count() or 1
        with LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                          dashboard_address=":0", silence_logs=logging.ERROR) as cluster, \
                Client(cluster) as client:
            yield client
