"""Preload of the local cluster's worker processes: warm a worker up while the study is validated.

Dask imports this module in each worker process it starts (``LocalCluster(preload=...)``) and calls
``dask_setup`` before the worker takes tasks. It ignores SIGINT (a Ctrl-C in the terminal reaches
the whole process group; the parent stops the study and closes the workers), keeps Dask's logging
to errors as the parent does, then runs the base
scenario for a few steps: the imports, the FMUs' unpacking and first instantiation and the compiled
kernels' loading, which would otherwise fall on each worker's first case, happen while the parent
is still validating the cases. A warm-up that fails is ignored: the cases then report the problem
with their own one-line errors. ``dask_teardown`` (the worker closing) freezes the garbage
collector, so the process's exit, which the study's end waits for, skips a final collection.
"""

from __future__ import annotations

import contextlib
import dataclasses
import gc
import logging
import os
import signal
from typing import Any

WARMUP_ENV = "SEAFMU_SWEEP_WARMUP"  # the base scenario's path, set for the worker processes
WARMUP_STEPS = 20


def warm_up(scenario: str) -> None:
    """Run ``scenario`` for a few master steps, without recording or checks."""
    from seafmu.master import run
    from seafmu.results import evaluate_checks  # noqa: F401  (imported by every case)
    from seafmu.scenario import load_scenario

    sc = load_scenario(scenario)
    short = dataclasses.replace(sc, duration=WARMUP_STEPS * sc.step, events=[], checks=[])
    run(short, mode="fmu", progress=False)


def dask_setup(worker: Any) -> None:
    with contextlib.suppress(ValueError):  # not the main thread: dask runs preloads in it
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    # as the parent's cluster (silence_logs): errors only, so a worker closed at the study's tail
    # does not print Dask's INFO lines into the terminal
    logging.getLogger("distributed").setLevel(logging.ERROR)
    scenario = os.environ.get(WARMUP_ENV)
    if scenario:
        with contextlib.suppress(Exception):
            warm_up(scenario)


def dask_teardown(worker: Any) -> None:
    # The worker is closing and its process exits next: objects frozen now are left out of the
    # interpreter's final collection (numba, pandas, Dask: ~0.5 s), which the study's end waits for.
    gc.freeze()
