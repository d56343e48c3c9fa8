"""Preload of the local cluster's worker processes: warm a worker up while the study is validated.

The workers fork from a server process (``seafmu.sweep.forkserver``) that imports this module first;
told so by its environment, the server then imports what a worker runs and warms up on the base
scenario, once for every worker forked from it. Dask also imports this module in each worker
(``LocalCluster(preload=...)``) and calls ``dask_setup`` before the worker takes tasks. It ignores
SIGINT (a Ctrl-C in the terminal reaches the whole process group; the parent stops the study and
closes the workers), keeps Dask's logging to errors as the parent does, pins the worker to a core
of its own when the parent asks (one worker per core: ``execute._pinning``), and warms up on the base
scenario unless the server did: a few steps of it, so that the imports, the FMUs' unpacking and
first instantiation and the compiled kernels' loading, which would otherwise fall on each worker's
first case, happen while the parent is still validating the cases. A warm-up that fails is
ignored: the cases then report the problem with their own one-line errors. ``dask_teardown`` (the
worker closing) freezes the garbage collector, so the process's exit, which the study's end waits
for, skips a final collection.
"""

from __future__ import annotations

import atexit
import contextlib
import dataclasses
import gc
import logging
import os
import signal
import sys
from collections.abc import Iterator
from typing import Any

from seafmu.sweep.forkserver import SERVER_ENV

WARMUP_ENV = "SEAFMU_SWEEP_WARMUP"  # the base scenario's path, set for the worker processes
PIN_ENV = "SEAFMU_SWEEP_CORES"  # the cores to pin the workers to, one each by name (execute._pinning)
WARMUP_STEPS = 20
_warmed: set[str] = set()  # scenarios this process (or the server it was forked from) ran already


@contextlib.contextmanager
def collector_paused() -> Iterator[None]:
    """No garbage collection while a burst of long-lived objects is made (imports, the validation, a
    warm-up), and those objects frozen after it (the sweep's parent and the fork server use it):
    they hold Dask, seafmu, numba, pandas and matplotlib, hundreds of thousands of objects that
    every full collection walked again (0.1-0.2 s each, about 1 s of a 40-case study's parent)
    though none of them becomes garbage."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        gc.freeze()
        if was:
            gc.enable()


def warm_up(scenario: str) -> None:
    """Run ``scenario`` for a few master steps, without recording or checks."""
    from seafmu.master import run
    from seafmu.results import evaluate_checks  # noqa: F401  (imported by every case)
    from seafmu.scenario import load_scenario

    sc = load_scenario(scenario)
    short = dataclasses.replace(sc, duration=WARMUP_STEPS * sc.step, events=[], checks=[])
    run(short, mode="fmu", progress=False)
    _warmed.add(scenario)


def _warm_server(scenario: str) -> None:
    """In the fork server: import what every worker runs and warm up on ``scenario`` (if any), with
    the collector paused, then freeze what was made: the forks' collections neither walk it nor copy
    the shared pages."""
    with collector_paused(), contextlib.suppress(Exception):  # the server must start whatever happens
        import distributed.nanny
        import distributed.worker  # noqa: F401

        import seafmu.sweep.worker  # noqa: F401

        if scenario:
            warm_up(scenario)


def pin(name: Any, cores: str) -> None:
    """Every thread of this worker on one of ``cores`` (by the worker's number); threads started later
    (the one that runs the cases) inherit it. Best effort: a worker left unpinned still runs."""
    with contextlib.suppress(ValueError, OSError):
        choices = [int(c) for c in cores.split(",")]
        core = {choices[int(name) % len(choices)]}
        for tid in os.listdir("/proc/self/task"):
            with contextlib.suppress(OSError):  # a thread that just ended
                os.sched_setaffinity(int(tid), core)


def _heartbeat_at_close(record: logging.LogRecord) -> bool:
    """Drop Dask's "Failed to communicate with scheduler during heartbeat" (an ERROR with a traceback):
    a local worker's scheduler is the sweep's own process, which ends the cluster, and a heartbeat in
    flight while it does (seen once in ~60 sweeps) is no failure; the worker goes on or is closed.
    A scheduler lost for real means the sweep's own process is gone, which its user sees anyway."""
    return not record.getMessage().startswith("Failed to communicate with scheduler during heartbeat")


def dask_setup(worker: Any) -> None:
    with contextlib.suppress(ValueError):  # not the main thread: dask runs preloads in it
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    # as the parent's cluster (silence_logs): errors only, so a worker closed at the study's tail
    # does not print Dask's INFO lines into the terminal
    logging.getLogger("distributed").setLevel(logging.ERROR)
    logging.getLogger("distributed.worker").addFilter(_heartbeat_at_close)
    if os.environ.get(PIN_ENV):
        pin(worker.name, os.environ[PIN_ENV])
    scenario = os.environ.get(WARMUP_ENV)
    if scenario and scenario not in _warmed:
        with contextlib.suppress(Exception):
            warm_up(scenario)


def dask_teardown(worker: Any) -> None:
    # The worker is closing and its process exits next: objects frozen now are left out of the
    # interpreter's final collection (numba, pandas, Dask: ~0.5 s), which the study's end waits for.
    gc.freeze()


def _exit_at_once() -> None:
    """The fork server's last exit handler (registered first, so it runs after every other one):
    the interpreter's own teardown of numba, LLVM and Dask (~0.04 s),
    which the sweep command waits for (``forkserver.stop``), has nothing left to do."""
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(0)


if SERVER_ENV in os.environ:  # imported by the fork server (its preload)
    atexit.register(_exit_at_once)
    _warm_server(os.environ[SERVER_ENV])
