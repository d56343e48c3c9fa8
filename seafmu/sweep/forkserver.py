"""The local cluster's worker processes fork from one warmed-up server instead of each starting Python.

Why: a worker process started from scratch (Dask's default, ``spawn``) spends ~1.3 s of CPU importing
Dask and seafmu, unpacking the FMUs and loading the compiled kernels, and on a 2-core machine two of
them compete with the study's validation and with each other. Python's ``forkserver`` start method
is made for this: a clean, single-threaded server process imports (``preload``) once, and each
worker is a fork of it (copy-on-write), ready in milliseconds; Dask supports it
(``distributed.worker.multiprocessing-method``). The server starts first thing (``seafmu sweep``
starts it before it even imports what reads the study: ``seafmu.sweep.cli._early_server``), so its
warm-up runs on the other core while this process validates the study's cases. It starts with the
environment Dask gives the worker processes it spawns (``WORKER_ENVIRON``: one BLAS thread each).

What the server preloads: ``seafmu.sweep.warm``, which (told so by ``SERVER_ENV``) imports Dask's
worker and seafmu and runs the study's base scenario for a few steps, so the FMUs are unpacked and
loaded and the kernels compiled-in before any worker forks. A worker that finds a different FMU
(another study in the same process, an FMU rebuilt meanwhile) loads it itself, as a spawned worker
would (``seafmu.master`` looks FMUs up by file and time; ``seafmu.fmu_cache`` unpacks each version
once and the server's hold on it is shared with its forks). One server per process: ``stop`` ends
it once the cluster is closed (the sweep command does), else it ends with this process.

Why forking it is safe where forking this process (Dask's ``fork``) is not: the server is a fresh
interpreter (started by exec) whose only thread forks, so no lock is held by a thread the fork
leaves behind.
"""

from __future__ import annotations

import contextlib
import os
import signal
from collections.abc import Iterator
from pathlib import Path

METHOD = "forkserver"
SERVER_ENV = "SEAFMU_SWEEP_SERVER_WARMUP"  # set only in the server's environment: the scenario to warm up on
PRELOAD = ["seafmu.sweep.warm"]
# What Dask puts in the environment of every worker process its nannies spawn (its default
# ``distributed.nanny.pre-spawn-environ``; tests/test_sweep_forkserver.py holds the two equal): one
# BLAS/OpenMP thread per process, as the cluster runs one process per core, and glibc's trim threshold.
# A forked worker's libraries are loaded in the server, so it is the server's environment that needs
# them: without, numpy's and SciPy's OpenBLAS each start a thread per core that spins ~0.1 s at load,
# on the critical path of the study's start. Not read from Dask's config: importing it first would
# delay the server by ~0.09 s.
WORKER_ENVIRON = {"MALLOC_TRIM_THRESHOLD_": "65536", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1",
                  "OPENBLAS_NUM_THREADS": "1"}
BLAS_THREADS = tuple(k for k in WORKER_ENVIRON if k.endswith("_NUM_THREADS"))


def single_threaded_blas() -> None:
    """One BLAS/OpenMP thread in this process (the sweep command's) unless its user set others: it runs
    no large linear algebra, and on a machine whose every core runs a worker the threads BLAS starts
    at load would take ~0.2 s of CPU from them. Call it before numpy is imported."""
    for var in BLAS_THREADS:
        os.environ.setdefault(var, WORKER_ENVIRON[var])


@contextlib.contextmanager
def _environ(updates: dict[str, str]) -> Iterator[None]:
    """``updates`` in os.environ inside the block (for a process started there), then as before."""
    before = {k: os.environ.get(k) for k in updates}
    os.environ.update(updates)
    try:
        yield
    finally:
        for k, v in before.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


@contextlib.contextmanager
def sigint_ignored() -> Iterator[None]:
    """Child processes started inside inherit SIGINT ignored (dispositions survive exec), so a Ctrl-C
    in the terminal, which reaches the whole process group, does not kill them mid-case; the study
    stops them."""
    try:
        old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the main thread
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


def start(warmup: Path | None) -> None:
    """Make the local cluster's workers forks of a server warmed up on ``warmup`` (the base scenario),
    starting that server now if this process has none; returns at once (the server warms up in the
    background; a worker's fork waits for it)."""
    import multiprocessing.forkserver

    multiprocessing.get_context(METHOD).set_forkserver_preload(PRELOAD)
    # PYTHONSAFEPATH: the server is `python -c ...`, which would put the current folder first on its
    # import path; run from the folder that holds a seafmu clone, `seafmu` there (no __init__.py at the
    # clone's top) became a namespace package ahead of the installed one, and every case failed
    with _environ({**WORKER_ENVIRON, SERVER_ENV: str(warmup or ""), "PYTHONSAFEPATH": "1"}), sigint_ignored():
        multiprocessing.forkserver.ensure_running()
    import dask.config  # after the server started: it warms up meanwhile
    import distributed.utils

    dask.config.set({"distributed.worker.multiprocessing-method": METHOD})
    # Dask's first forkserver worker would otherwise import pandas, numpy and lz4 here (0.35 s, in the
    # loop thread, before it asks for a fork) only to name them as the server's preload; this server
    # preloads what a worker runs already. A private flag (distributed 2022.x to 2026.x); without it
    # Dask only loses the time.
    distributed.utils._forkserver_preload_set = True


def stop() -> None:
    """End this process's fork server, if it has one, and wait for it: nothing of it is left when the
    command returns, and its CPU time, with its workers', counts among this process's children's
    (``getrusage``), as a spawned worker's did. Call it once the cluster is closed.

    Python has no public call for this; ``ForkServer._stop`` (3.8 to 3.13) closes the server's
    "alive" pipe, which is how the server learns its parent ended, and waits for it."""
    import multiprocessing.forkserver

    server = getattr(multiprocessing.forkserver, "_forkserver", None)
    if getattr(server, "_forkserver_pid", None) is None or not hasattr(server, "_stop"):
        return
    with contextlib.suppress(OSError):
        server._stop()
