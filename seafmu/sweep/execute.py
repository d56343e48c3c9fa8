"""Running a study on Dask: the cluster, the study folder, resume, Ctrl-C, the progress bar.

- Cluster: by default a local ``dask.distributed.LocalCluster`` of worker processes (one thread
  each, so each process holds one FMU set and runs one case at a time), listening on 127.0.0.1
  only, no dashboard. ``--scheduler tcp://HOST:8786`` (or ``DASK_SCHEDULER_ADDRESS``) connects to
  an existing cluster instead (``dask scheduler`` / ``dask worker``, dask-jobqueue on HPC); its
  workers need seafmu installed, the FMUs built and the scenario files at the same paths.
- Study folder: ``cases/<key>.json`` is written (atomically) as each case finishes, named by the
  case's key (a hash of the base scenario, its overrides, seed and what is computed): a rerun of
  the same study into the same folder skips every case whose row is there with the same key (a case
  its worker could not run is run again), so
  nothing is lost and nothing done twice; a changed study reruns only the cases it changed.
  ``cases.parquet`` is made from the rows at the end (also after an interruption). The folder is
  locked (flock) while a study runs in it.
- Start-up: the local cluster is started (``start_local_cluster``) while the study's cases are
  still being validated; its workers fork from a server that warms up meanwhile
  (``seafmu.sweep.forkserver``, ``seafmu.sweep.warm``: imports, FMUs, compiled kernels, once for
  all workers). Small studies hand each case its scenario as validated, so a worker does not
  validate it again. While the workers start, a background thread imports what cases.parquet and
  the report need; once the cases are in, the cluster closes in
  the background while they are written (``Outcome.close``).
- Stop: SIGINT, SIGTERM and SIGHUP only set a flag (``seafmu.master.stop_on_signals``); the loop
  then cancels the cases not finished, closes the client and the cluster, and keeps every row
  already written. Worker processes start with SIGINT ignored (inherited from their server, which
  the parent starts with SIGINT ignored, and set again by their preload), so a Ctrl-C in the
  terminal (which reaches the whole process group) does not kill them mid-case with tracebacks;
  the parent closes them.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import logging
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from seafmu.cores import core_count, usable_cores
from seafmu.master import StopRequest
from seafmu.outdir import SWEEP_LOCK_FILE, atomic_path, atomic_write_text
from seafmu.sweep import forkserver
from seafmu.sweep.study import Case, Study, StudyError
from seafmu.sweep.warm import PIN_ENV, WARMUP_ENV, collector_paused
from seafmu.sweep.worker import PASS, run_case

LOCK_FILE = SWEEP_LOCK_FILE
ROWS = "cases"
STOP_POLL_S = 0.1  # how soon a stop is seen while the cases run (s)
SERIES = "timeseries"


class StudyFolder:
    """``with StudyFolder(path):`` the folder created and locked for this study run."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._fd: int | None = None

    def __enter__(self) -> StudyFolder:
        (self.path / ROWS).mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            owner = os.pread(fd, 32, 0).decode("ascii", "replace").strip()
            os.close(fd)
            who = f" (pid {owner})" if owner.isdigit() else ""
            raise StudyError(f"{self.path}: in use by another seafmu sweep{who}; wait for it or use "
                             "--out") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd = fd
        return self

    def __exit__(self, *exc: object) -> None:
        if self._fd is not None:
            fcntl.flock(self._fd, fcntl.LOCK_UN)
            os.close(self._fd)
            self._fd = None

    def row_path(self, case: Case) -> Path:
        """Named by the case's key, not its number: a study that gains or loses a grid value renumbers
        its cases, and each finished one is still found."""
        return self.path / ROWS / f"{case.key}.json"

    def finished(self, study: Study) -> dict[int, dict[str, Any]]:
        """Rows already in the folder for these very cases (same key); others are ignored."""
        done = {}
        for c in study.cases:
            p = self.row_path(c)
            try:
                row = json.loads(p.read_text(encoding="utf-8"))
            except (OSError, ValueError):
                continue
            if isinstance(row, dict) and row.get("key") == c.key and not _worker_failed(row):
                done[c.index] = {**row, "case": c.index}
        return done

    def write_row(self, case: Case, row: dict[str, Any]) -> None:
        series = row.pop("_series", None)
        if series is not None:
            import pandas as pd

            (self.path / SERIES).mkdir(exist_ok=True)
            with atomic_path(self.path / SERIES / f"{case.key}.parquet") as tmp:
                pd.DataFrame(series).to_parquet(tmp, engine="pyarrow", index=False)
        atomic_write_text(self.row_path(case), json.dumps(row, default=_plain) + "\n")


def _plain(x: Any) -> Any:
    if isinstance(x, np.generic):
        return x.item()
    return str(x)


def cases_frame(study: Study, rows: dict[int, dict[str, Any]]) -> Any:
    """One row per finished case, in case order, with the reproducing command; columns of mixed
    types become text and pass columns nullable booleans, so Parquet can hold them."""
    import pandas as pd

    recs = []
    for c in study.cases:
        r = rows.get(c.index)
        if r is None:
            continue
        rec = dict(r)
        rec["sample"] = c.sample
        rec["overrides"] = " ".join(c.overrides)
        rec["command"] = c.command(study.scenario_arg)
        if study.model.keep:
            rec["timeseries"] = f"{SERIES}/{c.key}.parquet"
        recs.append(rec)
    frame = pd.DataFrame.from_records(recs)
    if frame.empty:
        return frame
    for col in frame.columns:
        if col.startswith(PASS):
            frame[col] = frame[col].astype("boolean")
        elif frame[col].dtype == object:
            kinds = {type(v) for v in frame[col]
                     if v is not None and not (isinstance(v, float) and np.isnan(v))}
            if len(kinds) > 1:
                frame[col] = frame[col].map(lambda v: None if v is None else str(v))
    return frame


def write_cases(study: Study, folder: StudyFolder, rows: dict[int, dict[str, Any]]) -> Path:
    frame = cases_frame(study, rows)
    path = folder.path / "cases.parquet"
    with atomic_path(path) as tmp:
        frame.to_parquet(tmp, engine="pyarrow", index=False)
    return path


# Dask's periodic housekeeping, set for the local cluster (its workers and this process's scheduler and
# nannies). Each case is pure Python in the worker's task thread, and whatever else runs in the
# process takes the GIL from it: the worker's statistical profiler (every 10 ms, walking the case's
# stack, for a dashboard this cluster does not have), the event loops' tick monitors (20 ms), the
# system monitors (500 ms), the nannies' memory checks (100 ms). Off or slowed, a case takes ~4 %
# less CPU and, with as many workers as cores, loses ~2 % less to this process
# (benchmarks/bench_sweep.py). Memory is still checked every second, a blocked loop still reported.
QUIET = {"distributed.worker.profile.enabled": False, "distributed.admin.tick.interval": "1s",
         "distributed.admin.system-monitor.interval": "2s",
         "distributed.worker.memory.monitor-interval": "1s"}


def _pinning(workers: int) -> dict[str, str]:
    """Each worker on a core of its own (``warm.dask_setup`` pins it) when there is one worker per core
    this process may use, 2 or more. Why: three busy processes on two cores (the workers and this
    one's scheduler) make Linux move the workers between cores, and a case then takes ~3 % more CPU
    (cold caches) than alone: benchmarks/bench_sweep.py, 2 workers. Fewer workers than cores (another
    study may use the rest) stay free to move."""
    cores = usable_cores()
    return {PIN_ENV: ",".join(map(str, cores))} if cores and 1 < workers == len(cores) else {}


def start_local_cluster(workers: int, warmup: Path | None = None) -> Any:
    """A local cluster of ``workers`` processes (one thread each, 127.0.0.1, no dashboard), returned
    at once: the processes fork from the warmed-up server (``seafmu.sweep.forkserver``, started
    here first) and register while the caller goes on; tasks submitted meanwhile wait for them."""
    forkserver.start(warmup)
    import dask.config
    from distributed import LocalCluster

    dask.config.set(QUIET)  # read by the scheduler and the nannies here, passed by them to the workers

    cluster = LocalCluster(n_workers=0, threads_per_worker=1, processes=True, host="127.0.0.1",
                           dashboard_address=None, silence_logs=logging.ERROR, preload=["seafmu.sweep.warm"],
                           # no dashboard; the scheduler's own HTTP routes (health) on a free loopback
                           # port, not on 8787 (taken by any other Dask cluster: a warning)
                           scheduler_kwargs={"dashboard_address": "127.0.0.1:0"},
                           env={**({WARMUP_ENV: str(warmup)} if warmup is not None else {}),
                                **_pinning(workers)})
    try:
        cluster.scale(workers)
    except BaseException:
        with contextlib.suppress(Exception):
            cluster.close(timeout=10)
        raise
    return cluster


def make_client(workers: int | None, scheduler: str | None, cluster: Any = None) -> tuple[Any, Any]:
    """(client, local cluster or None): an existing scheduler if one is named, else ``cluster``
    (started already) or a new local one."""
    from distributed import Client

    address = scheduler_address(scheduler)
    if address:
        try:
            return Client(address, timeout="15s"), None
        except (OSError, TimeoutError, ValueError) as exc:
            where = "--scheduler" if scheduler else "DASK_SCHEDULER_ADDRESS"
            raise StudyError(f"{where} {address}: cannot connect ({' '.join(str(exc).split())})") from None
    if cluster is None:
        cluster = start_local_cluster(workers or core_count())
    # By address, not Client(cluster), which waits until every worker has started: the cases go out at
    # once and each worker takes them as it registers (the first one ~0.1 s sooner with two).
    return Client(cluster.scheduler_address), cluster


def scheduler_address(scheduler: str | None) -> str | None:
    """The existing scheduler a study runs on (``--scheduler``, else DASK_SCHEDULER_ADDRESS), or None."""
    return scheduler or os.environ.get("DASK_SCHEDULER_ADDRESS") or None


def _import_for_results(rank_correlations: bool) -> None:
    """What cases.parquet and the report import, loaded while the local cluster's workers start (this
    process waits for them: they fork from a server still warming up) rather than while the cases
    run, where it took ~0.4 s of CPU from the workers when they are as many as the cores.
    ``rank_correlations``: the study varies an input, so the report computes them."""
    with collector_paused(), contextlib.suppress(Exception):
        import matplotlib.backends.backend_agg
        import matplotlib.figure  # noqa: F401
        import pandas  # noqa: F401
        import pyarrow.parquet  # noqa: F401

        if rank_correlations:
            import scipy.special  # noqa: F401  (their p-values: ~0.13 s)


def _retire_idle(client: Any, cluster: Any, retired: set[str], left: int) -> None:
    """Close the local workers with nothing left to run (the study's tail: fewer cases left than
    workers), in the background, so their shutdown overlaps the last cases instead of following
    them; ``retired`` gains their addresses. Through the cluster (``scale_down``), so that its final
    close waits for this one instead of racing it."""
    try:
        info = client.scheduler_info()["workers"]
        held = client.has_what()  # a result not fetched yet stays where it is: its worker is not idle
        idle = [w for w, keys in client.processing().items()
                if not keys and not held.get(w) and w not in retired and w in info]
    except Exception:
        return
    idle = idle[:max(0, len(info) - len(retired) - left)]  # as many workers as cases left stay
    if not idle:
        return
    retired.update(idle)
    names = [info[w]["name"] for w in idle]

    def retire() -> None:
        with contextlib.suppress(Exception):
            cluster.sync(cluster.scale_down, names)

    threading.Thread(target=retire, name="seafmu-sweep-retire", daemon=True).start()


WORKER_FAILED = "the worker running this case failed"


def _error_row(c: Case, exc: BaseException) -> dict[str, Any]:
    """The row of a case whose task failed outside ``run_case`` (its worker process died)."""
    return {"case": c.index, "key": c.key, "seed": c.seed, **c.inputs, "status": "error",
            "error": f"{WORKER_FAILED} ({type(exc).__name__}: {' '.join(str(exc).split())[:300]})",
            "wall_time_s": float("nan")}


def _worker_failed(row: dict[str, Any]) -> bool:
    """A row of a case its worker could not run (the process died, the machine ran out of memory):
    not the case's own outcome, so a rerun of the study runs it again."""
    return row.get("status") == "error" and str(row.get("error", "")).startswith(WORKER_FAILED)


def _closer(client: Any, cluster: Any) -> Callable[[], None]:
    """Close the client and the local cluster in a background thread; the returned call waits."""
    def close() -> None:
        with contextlib.suppress(Exception):
            client.close(timeout=10)
        if cluster is not None:
            with contextlib.suppress(Exception):
                cluster.close(timeout=10)

    t = threading.Thread(target=close, name="seafmu-sweep-close", daemon=True)
    t.start()
    return lambda: t.join(timeout=30)


@dataclass
class Outcome:
    total: int
    skipped: int  # finished before this run
    ran: int  # finished in this run
    interrupted: str  # the signal's name, or ""
    rows: dict[int, dict[str, Any]]
    wall_time: float
    workers: int
    close: Callable[[], None] = field(default=lambda: None)  # waits until the cluster is closed


def _wait_for_a_case(ac: Any, timeout: float = STOP_POLL_S) -> None:
    """Sleep until a case finishes (``as_completed`` notifies its condition after queueing the row,
    so the queue is checked under it) or ``timeout`` passes, so that a stop (a flag set by the
    signal handler) is seen within it. Where this loop polled every 10 ms instead, the sweep's
    process took ~1 % of a core from the workers while the cases ran."""
    with ac.thread_condition:
        if ac.queue.empty():
            ac.thread_condition.wait(timeout)


def _task(study: Study, c: Case) -> dict[str, Any]:
    return {"case": c.index, "key": c.key, "seed": c.seed, "inputs": c.inputs, "overrides": c.overrides,
            "scenario": str(study.scenario_file), "resolved": study.scenarios.get(c.index),
            "metrics": [m.model_dump() for m in study.model.metrics], "keep": list(study.model.keep)}


def run_study(study: Study, folder: StudyFolder, workers: int | None = None, scheduler: str | None = None,
              progress: bool = True, stop: StopRequest | None = None, cluster: Any = None) -> Outcome:
    """Run the cases not finished yet on Dask; rows are written as cases finish. ``cluster``: a
    local cluster started already (``start_local_cluster``); it is closed here. The returned
    outcome's ``close()`` waits for the cluster to be closed (in the background)."""
    from distributed import as_completed
    from distributed.utils import CancelledError

    stop = stop or StopRequest()
    rows = folder.finished(study)
    skipped = len(rows)
    todo = [c for c in study.cases if c.index not in rows]
    t0 = time.perf_counter()
    if not todo:
        if cluster is not None:
            cluster.close(timeout=10)
        return Outcome(len(study.cases), skipped, 0, "", rows, 0.0, 0)
    n_workers = min(workers or core_count(), len(todo))
    threading.Thread(target=_import_for_results, args=(bool(study.inputs),), name="seafmu-sweep-imports",
                     daemon=True).start()
    try:
        client, cluster = make_client(n_workers, scheduler, cluster)
    except BaseException:
        if cluster is not None:
            with contextlib.suppress(Exception):
                cluster.close(timeout=10)
        raise
    bar, ran, futures = None, 0, {}
    try:
        if cluster is not None:
            n_workers = len(cluster.worker_spec)
        for c in todo if not stop.requested else []:  # a signal during the validation: submit nothing
            fut = client.submit(run_case, _task(study, c), key=f"seafmu-case-{c.index}-{c.key}", pure=False)
            futures[fut] = c
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=len(study.cases), initial=skipped, desc=study.name, unit="case", smoothing=0.1)
        # with_results: each row is fetched by the client's event loop as its case ends, so this loop
        # never waits on a fetch
        ac = as_completed(list(futures), with_results=True)
        retired: set[str] = set()
        skipped_now = 0
        fails = sum(1 for r in rows.values() if r.get("status") != "pass")
        while not ac.is_empty() and not stop.requested:
            batch = ac.next_batch(block=False)
            if not batch:
                _wait_for_a_case(ac)
                continue
            for fut, result in batch:
                c = futures[fut]
                if isinstance(result, CancelledError):  # what a cancelled future gives as its result
                    skipped_now += 1
                    continue
                row = _error_row(c, fut.exception()) if fut.status == "error" else result
                folder.write_row(c, row)
                rows[c.index] = row
                ran += 1
                fails += row["status"] != "pass"
                if bar is not None:
                    bar.update(1)
                    bar.set_postfix(failed=fails, refresh=False)
                fut.release()
            left = len(futures) - ran - skipped_now
            if cluster is not None and 0 < left < n_workers - len(retired):
                _retire_idle(client, cluster, retired, left)
    finally:
        if bar is not None:
            bar.close()
        pending = [f for f in futures if not f.done()]
        if pending:
            with contextlib.suppress(Exception):
                client.cancel(pending)
        close = _closer(client, cluster)
    if cluster is None:  # an existing cluster: the workers that ran the cases (one may register late)
        n_workers = len({rows[c.index].get("worker") for c in futures.values() if c.index in rows})
    return Outcome(len(study.cases), skipped, ran, stop.name if stop.requested else "", rows,
                   time.perf_counter() - t0, n_workers, close)
