"""Test processes share the machine's cores (``pytest -n auto``: one process per core).

torch and OpenMP default to one thread per core in every process, so two test processes on
two cores ran four busy threads, and OpenMP threads spinning while they wait for each other
made training tests 2-10x slower whenever the other process trained too. One thread per
process, inherited by the command-line tools the tests start.
"""

import os

if os.environ.get("PYTEST_XDIST_WORKER"):
    os.environ.setdefault("OMP_NUM_THREADS", "1")
