"""Sweep workers fork from a warmed-up server: what that changes and what must not change.

- The local cluster's workers are forks of multiprocessing's fork server, which loaded the study's
  FMUs once; a worker's case runs on them without unpacking its own copy, and gives the same row
  as a case run in this process.
- A forked process runs on its parent's unpacked FMUs, and its end leaves them held by the parent
  (the parent's next run still works; they are not taken for unused).
- A server whose warm-up fails (a scenario that does not load) still serves workers that run cases.

Each runs in a fresh interpreter: the fork server lives as long as the process that started it.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
from test_run_robustness import _default_signals, _unheld_versions
from test_sweep import SCENARIO


def _python(code: str, cwd: Path, env: dict[str, str] | None = None) -> str:
    proc = subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True, timeout=300,
                          env={**os.environ, **(env or {})})
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout


def _base(tmp_path: Path) -> Path:
    path = tmp_path / "base.yaml"
    path.write_text(SCENARIO.format(duration=3))
    return path


WORKERS_ARE_FORKS = """
import json, os, sys, multiprocessing.forkserver as mpfs
from distributed import Client
import seafmu.master as m
from seafmu.scenario import load_scenario
from seafmu.sweep.execute import start_local_cluster
from seafmu.sweep.worker import run_case

def where():
    import dask.config
    import seafmu.master as m
    from seafmu import fmu_cache
    return {"pid": os.getpid(), "ppid": os.getppid(), "extracted": sorted(m._EXTRACTED.values()),
            "held": sorted(str(v) for v in fmu_cache._held),
            "profiler": dask.config.get("distributed.worker.profile.enabled"),
            "blas_threads": [i["num_threads"] for i in __import__("threadpoolctl").threadpool_info()
                             if i["user_api"] == "blas"],
            "cores": sorted(os.sched_getaffinity(0))}

cluster = start_local_cluster(2, "base.yaml")
client = Client(cluster)
client.wait_for_workers(2)
pandas_at_start = "pandas" in sys.modules  # Dask's own forkserver set-up imports it; ours does not
task = {"case": 0, "key": "k", "seed": 4, "inputs": {}, "overrides": [], "scenario": "base.yaml",
        "resolved": None, "metrics": [], "keep": []}
remote = client.submit(run_case, task, pure=False).result()
before = client.run(where)
local = run_case(task)
client.close(); cluster.close()
print(json.dumps({"server": mpfs._forkserver._forkserver_pid, "me": os.getpid(),
                  "preload": mpfs._forkserver._preload_modules,
                  "workers": list(before.values()), "remote": remote, "local": local,
                  "pandas_at_start": pandas_at_start}))
"""


def test_workers_fork_from_a_server_that_loaded_the_fmus(tmp_path: Path, built_fmus: object) -> None:
    _base(tmp_path)
    out = json.loads(_python(WORKERS_ARE_FORKS, tmp_path).strip().splitlines()[-1])
    assert len(out["workers"]) == 2 and out["server"] not in (None, out["me"])
    for w in out["workers"]:
        assert w["ppid"] == out["server"]  # forked by the server, not started by this process
        # the server's four unpacked FMUs, looked up and held by it, none by the worker itself
        assert len(w["extracted"]) == 4 and w["held"] == w["extracted"]
        assert w["profiler"] is False  # execute.QUIET reached the worker: nothing samples the case's stack
        assert w["blas_threads"] and set(w["blas_threads"]) == {1}  # as in a worker Dask spawns itself
    cores = sorted(os.sched_getaffinity(0))
    if len(cores) == 2:  # one worker per core: each pinned to its own (execute._pinning)
        assert sorted(c for w in out["workers"] for c in w["cores"]) == cores
    else:
        assert all(w["cores"] == cores for w in out["workers"])
    # Dask kept the server seafmu started (its preload) and did not import pandas & co. for one of its own
    assert out["preload"] == ["seafmu.sweep.warm"] and not out["pandas_at_start"]
    skip = {"wall_time_s", "cpu_time_s", "loop_time_s", "run_time_s", "realtime_factor", "started",
            "finished", "worker"}
    remote, local = ({k: v for k, v in r.items() if k not in skip} for r in (out["remote"], out["local"]))
    assert remote["status"] in ("pass", "fail") and remote == local


FORKED_CHILD = """
import fcntl, json, os, sys
from pathlib import Path
import seafmu.master as m
from seafmu import fmu_cache
from seafmu.scenario import load_scenario

def held_elsewhere(version):
    # another open file description cannot take the lock exclusively while a process holds it shared
    fd = os.open(version / fmu_cache.LOCK, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        return False
    except OSError:
        return True
    finally:
        os.close(fd)

sc = load_scenario("base.yaml")
m.run(sc, mode="fmu", progress=False)
mine = sorted(fmu_cache._held)
pid = os.fork()
if pid == 0:  # the child: runs on the parent's FMUs, then unpacks one more
    m.run(sc, mode="fmu", progress=False)
    shared = sorted(fmu_cache._held) == mine
    extra = m._extract(Path(sys.argv[1]))
    Path("child.json").write_text(json.dumps({"shared": shared, "extra": extra}))
    sys.exit(0)
_, status = os.waitpid(pid, 0)
child = json.loads(Path("child.json").read_text())
after = {"status": status, "mine_held": all(held_elsewhere(v) for v in mine),
         "extra_free": not held_elsewhere(Path(child["extra"]))}
m.run(sc, mode="fmu", progress=False)  # the parent's FMUs still work
print(json.dumps({**child, **after}))
"""


def test_a_forked_child_leaves_its_parents_fmus_held(tmp_path: Path, built_fmus: dict) -> None:
    _base(tmp_path)
    code = FORKED_CHILD.replace('sys.argv[1]', repr(str(built_fmus[("amv_osf", "plant")])))
    out = json.loads(_python(code, tmp_path, {"SEAFMU_FMU_CACHE": str(tmp_path / "cache")})
                     .strip().splitlines()[-1])
    assert out["status"] == 0 and out["shared"]
    assert out["mine_held"]  # the child's end did not release what the parent holds
    assert out["extra_free"]  # what the child alone held was released when it ended


FAILED_WARMUP = """
import json, os
from distributed import Client
from seafmu.sweep.execute import start_local_cluster
from seafmu.sweep.worker import run_case

cluster = start_local_cluster(1, "no_such_scenario.yaml")
client = Client(cluster)
task = {"case": 0, "key": "k", "seed": 2, "inputs": {}, "overrides": [], "scenario": "base.yaml",
        "resolved": None, "metrics": [], "keep": []}
row = client.submit(run_case, task, pure=False).result()
client.close(); cluster.close()
print(json.dumps(row))
"""


def test_a_server_whose_warm_up_fails_still_serves_workers(tmp_path: Path, built_fmus: object) -> None:
    _base(tmp_path)
    row = json.loads(_python(FAILED_WARMUP, tmp_path).strip().splitlines()[-1])
    assert row["status"] in ("pass", "fail") and not row["error"] and row["simulated_s"] == pytest.approx(3.0)


def test_the_sweep_command_ends_its_server_and_counts_its_workers_cpu(tmp_path: Path,
                                                                     built_fmus: object) -> None:
    """When `seafmu sweep` returns, the fork server has ended (nothing left in the temporary folder
    but Dask's lock files, its unpacked FMUs held by no process) and was waited for: the command's
    children's CPU time includes every case's CPU time, which the workers (the server's children)
    spent."""
    import resource

    import pandas as pd

    _base(tmp_path)
    (tmp_path / "study.yaml").write_text("name: s\nscenario: base.yaml\nseeds: 4\n")
    tmpdir = tmp_path / "tmp"
    tmpdir.mkdir()
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    proc = subprocess.run([sys.executable, "-m", "seafmu.cli", "sweep", "study.yaml", "--workers", "2",
                           "--out", "out", "-q"], cwd=tmp_path, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "TMPDIR": str(tmpdir),
                               "SEAFMU_FMU_CACHE": str(tmp_path / "cache")})
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    assert proc.returncode in (0, 1), proc.stderr
    left = {str(p.relative_to(tmpdir)) for p in tmpdir.rglob("*")}
    assert left <= {"dask-scratch-space", "dask-scratch-space/global.lock", "dask-scratch-space/purge.lock"}
    assert len(_unheld_versions(tmp_path / "cache")) == 4
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    cases = pd.read_parquet(tmp_path / "out" / "cases.parquet")
    assert len(cases) == 4 and cases["worker"].nunique() == 2
    assert cpu > cases["cpu_time_s"].sum() + 0.5  # the cases, and the parent's and server's own work


def test_ctrl_c_to_the_whole_process_group(tmp_path: Path, built_fmus: object) -> None:
    """A Ctrl-C in a terminal reaches every process of the group: the parent, the fork server and
    the workers forked from it. Only the parent acts on it: exit 130, one line on stderr, no
    traceback from a worker or the server, the finished rows kept, no process left behind."""
    import time

    _base(tmp_path)
    (tmp_path / "base.yaml").write_text(SCENARIO.format(duration=150))
    (tmp_path / "study.yaml").write_text("name: s\nscenario: base.yaml\nseeds: 12\n")
    rows = tmp_path / "out" / "cases"
    proc = subprocess.Popen([sys.executable, "-m", "seafmu.cli", "sweep", "study.yaml", "--workers", "2",
                             "--out", "out", "-q"], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=_default_signals)
    deadline = time.monotonic() + 180
    while time.monotonic() < deadline and len(list(rows.glob("*.json")) if rows.is_dir() else []) < 2:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert err.count("\n") == 1 and err.startswith("seafmu: sweep interrupted (SIGINT)"), err
    kept = len(list(rows.glob("*.json")))
    assert 2 <= kept < 12
    deadline = time.monotonic() + 10  # what is left of the group (exiting children) ends by itself
    while time.monotonic() < deadline:
        try:
            os.killpg(proc.pid, 0)
        except ProcessLookupError:
            break
        time.sleep(0.05)
    else:
        pytest.fail("processes of the study are left behind 10 s after it stopped")


def test_workers_are_pinned_only_when_there_is_one_per_core(tmp_path: Path) -> None:
    from seafmu.sweep.execute import _pinning
    from seafmu.sweep.warm import PIN_ENV

    cores = sorted(os.sched_getaffinity(0))
    assert _pinning(1) == {} and _pinning(len(cores) + 1) == {}  # fewer or more workers than cores: free
    assert _pinning(len(cores)) == ({PIN_ENV: ",".join(map(str, cores))} if len(cores) > 1 else {})
    # in a child (never this process): every thread, and a thread started afterwards, on the named core
    code = f"""
import json, os, threading
from seafmu.sweep.warm import pin
threading.Thread(target=lambda: threading.Event().wait(2), daemon=True).start()
pin(3, "{",".join(map(str, cores))}")
later = []
t = threading.Thread(target=lambda: later.append(sorted(os.sched_getaffinity(0)))); t.start(); t.join()
tids = os.listdir("/proc/self/task")
every = sorted({{c for tid in tids for c in os.sched_getaffinity(int(tid))}})
print(json.dumps([every, later[0], len(tids)]))
"""
    every, later, threads = json.loads(_python(code, tmp_path).strip().splitlines()[-1])
    assert every == later == [cores[3 % len(cores)]] and threads >= 2


def test_a_local_workers_heartbeat_at_close_is_not_printed(tmp_path: Path) -> None:
    """The local workers' preload drops Dask's heartbeat ERROR (with its traceback) that a worker
    logs when the sweep's own scheduler closes under it; other worker errors still print."""
    code = """
import io, logging
from seafmu.sweep.warm import dask_setup
class Worker:
    name = 0
dask_setup(Worker())
log = logging.getLogger("distributed.worker")
buf = io.StringIO()
log.addHandler(logging.StreamHandler(buf))
try:
    raise OSError("stream closed")
except OSError:
    log.exception("Failed to communicate with scheduler during heartbeat.")
log.error("Unexpected exception during heartbeat. Closing worker.")
print(repr(buf.getvalue()))
"""
    env = {k: "" for k in ("SEAFMU_SWEEP_WARMUP", "SEAFMU_SWEEP_CORES")}
    out = _python(code, tmp_path, env).strip().splitlines()[-1]
    assert "Unexpected exception during heartbeat" in out
    assert "Failed to communicate" not in out and "stream closed" not in out


def test_the_servers_environment_is_the_one_dask_gives_its_workers() -> None:
    """forkserver.WORKER_ENVIRON is Dask's default for the worker processes its nannies spawn; a
    forked worker's libraries were loaded in the server, so the server is started with it."""
    import dask.config
    import distributed  # noqa: F401  (loads Dask's distributed defaults)

    from seafmu.sweep.forkserver import WORKER_ENVIRON

    dask_default = dask.config.get("distributed.nanny.pre-spawn-environ")
    assert WORKER_ENVIRON == {k: str(v) for k, v in dask_default.items()}


BLAS_OF_THE_COMMAND = """
import seafmu.cli
seafmu.cli.build_parser("sweep")  # what `seafmu sweep` does before it runs
import numpy, scipy.linalg  # the study's validation loads both
from threadpoolctl import threadpool_info
print(sorted({i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}))
"""


def test_the_sweep_command_runs_blas_on_one_thread_unless_told_otherwise(tmp_path: Path) -> None:
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "MKL_NUM_THREADS",
                                                              "OPENBLAS_NUM_THREADS")}
    run = subprocess.run([sys.executable, "-c", BLAS_OF_THE_COMMAND], cwd=tmp_path, capture_output=True,
                         text=True, timeout=120, env=env)
    assert run.returncode == 0 and run.stdout.split() == ["[1]"], run.stderr[-2000:]
    if len(os.sched_getaffinity(0)) > 1:  # the user's own setting is kept
        told = subprocess.run([sys.executable, "-c", BLAS_OF_THE_COMMAND], cwd=tmp_path, capture_output=True,
                              text=True, timeout=120, env={**env, "OPENBLAS_NUM_THREADS": "2"})
        assert told.returncode == 0 and told.stdout.split() == ["[2]"], told.stderr[-2000:]


def test_the_server_starts_before_the_study_is_read_when_its_scenario_is_a_file(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """seafmu sweep starts the fork server first thing, on the base scenario as load_study finds it;
    not for a dry run, an existing scheduler, a shipped scenario's name or a study that does not read."""
    import argparse

    from seafmu.sweep import cli, forkserver
    from seafmu.sweep.study import load_study

    started: list[Path | None] = []
    monkeypatch.setattr(forkserver, "start", started.append)
    monkeypatch.delenv("DASK_SCHEDULER_ADDRESS", raising=False)
    (tmp_path / "sub").mkdir()
    _base(tmp_path / "sub")
    study = tmp_path / "sub" / "study.yaml"
    study.write_text("name: s\nscenario: base.yaml\nseeds: 2\n")

    def args(path: Path, **kw: object) -> argparse.Namespace:
        return argparse.Namespace(**{"study": str(path), "dry_run": False, "scheduler": None, **kw})

    monkeypatch.chdir(tmp_path)
    cli._early_server(args(study.relative_to(tmp_path)))
    assert started == [load_study(study, validate=False).scenario_file.resolve()]
    for kw in ({"dry_run": True}, {"scheduler": "tcp://127.0.0.1:8786"}):
        cli._early_server(args(study, **kw))
    monkeypatch.setenv("DASK_SCHEDULER_ADDRESS", "tcp://127.0.0.1:8786")
    cli._early_server(args(study))
    monkeypatch.delenv("DASK_SCHEDULER_ADDRESS")
    for text in ("name: s\nscenario: minerva2_dp\nseeds: 2\n", "name: s\nscenario: nope.yaml\n",
                 "name: [s\n", "- a list\n"):
        study.write_text(text)
        cli._early_server(args(study))
    cli._early_server(args(tmp_path / "missing.yaml"))
    assert len(started) == 1


WORKER_DIES = """
import json
from pathlib import Path
Path("dier.py").write_text("import os\\ndef run_case(task):\\n    os._exit(3)\\n")
import dier
import seafmu.sweep.execute as ex
from seafmu.sweep.study import load_study, validate_cases

real = ex.run_case
ex.run_case = dier.run_case  # pickled by reference: the worker imports dier (on PYTHONPATH)
study = load_study("study.yaml", validate=False)
validate_cases(study)
with ex.StudyFolder(Path("out")) as folder:
    out = ex.run_study(study, folder, workers=1, progress=False)
    out.close()
ex.run_case = real  # the study again into its folder: the cases its worker could not run, run now
with ex.StudyFolder(Path("out")) as folder:
    again = ex.run_study(study, folder, workers=1, progress=False)
    again.close()
statuses = sorted(r["status"] for r in again.rows.values())
print(json.dumps([list(out.rows.values()), [again.skipped, again.ran, statuses]]))
"""


def test_a_case_whose_worker_process_dies_is_recorded_and_the_study_goes_on(tmp_path: Path,
                                                                         built_fmus: object) -> None:
    """A worker process that dies mid-case (here it exits at once) never stops the study: once Dask
    gives up on the case, it is a row with status error and the one-line reason. Not the case's own
    outcome: a rerun of the study into its folder runs those cases again (not skipped as finished)."""
    _base(tmp_path)
    (tmp_path / "study.yaml").write_text("name: s\nscenario: base.yaml\nseeds: 2\n")
    env = {"DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES": "0", "PYTHONPATH": str(tmp_path)}
    rows, (skipped, ran, statuses) = json.loads(_python(WORKER_DIES, tmp_path, env).strip().splitlines()[-1])
    assert len(rows) == 2
    for r in rows:
        assert r["status"] == "error" and r["error"].startswith("the worker running this case failed (")
        assert "\n" not in r["error"]
    assert (skipped, ran) == (0, 2) and set(statuses) <= {"pass", "fail"}


def test_a_sweep_run_beside_a_seafmu_clone_imports_the_installed_seafmu(tmp_path: Path,
                                                                        built_fmus: object) -> None:
    """Run from the folder that holds a clone (a `seafmu` folder with no __init__.py at its top, and
    a results/ folder from an earlier run): the fork server, a `python -c`, put the current folder
    first on its import path, `seafmu` became that folder as a namespace package and every case
    failed (ImportError: cannot import name 'evaluate_checks' from 'seafmu.results')."""
    import pandas as pd

    _base(tmp_path)
    (tmp_path / "seafmu" / "results" / "minerva2_dp").mkdir(parents=True)
    (tmp_path / "study.yaml").write_text("name: s\nscenario: base.yaml\nseeds: 2\n")
    seafmu = Path(sys.executable).with_name("seafmu")  # the console script, as a user runs it
    proc = subprocess.run([str(seafmu), "sweep", "study.yaml", "--workers", "2", "--out", "out", "-q"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "SEAFMU_FMU_CACHE": str(tmp_path / "cache")})
    assert proc.returncode in (0, 1), proc.stderr
    cases = pd.read_parquet(tmp_path / "out" / "cases.parquet")
    assert len(cases) == 2 and set(cases["status"]) <= {"pass", "fail"}, cases["error"].tolist()
