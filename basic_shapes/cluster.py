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
    """
    import dask
    from distributed import Client, LocalCluster

    with dask.config.set({"distributed.worker.daemon": False}):
        if scheduler:
            with Client(scheduler) as client:
                yield client
            return
        n = workers or os.cpu_count() or 1
        with LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                          dashboard_address=":0", silence_logs=logging.ERROR) as cluster, \
                Client(cluster) as client:
            yield client
