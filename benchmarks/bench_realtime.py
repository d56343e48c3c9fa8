"""Benchmark: real-time pacing quality of the hardware loop over a 60 s run.

The vessel emulator runs in a second process behind pseudo-terminals (NMEA 0183 serial + SLCAN);
seafmu's observer, controller and allocator FMUs run here with the hardware link in the plant's
place (minerva2_dp, DP at 5 m depth). Printed: the real-time factor over the run and over 10 s
wall-clock windows, and the step jitter (lateness of each step's start against the wall-clock
schedule) p50 / p99 / max. Goals: factor 1.00 +- 0.01, p99 jitter under 5 ms.

    python benchmarks/bench_realtime.py [--duration 60] [--no-emulator] [--rt-priority 10]

``--no-emulator`` paces the same FMUs with the simulated plant instead (the pacer alone, no I/O).
"""

from __future__ import annotations

import argparse
import dataclasses
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import yaml

from seafmu.build import build_fmu
from seafmu.hardware.pacing import Pacer, PacingStats
from seafmu.hardware.profile import load_profile
from seafmu.master import run
from seafmu.scenario import load_scenario

REPO = Path(__file__).resolve().parents[1]


def _hil_scenario(tmp: Path, duration: float) -> Path:
    """minerva2_dp with the plant replaced by the bundled emulator_pty hardware profile."""
    doc = yaml.safe_load((REPO / "scenarios" / "minerva2_dp.yaml").read_text())
    doc.update(name="minerva2_dp_hil", duration=duration, checks=[])
    doc["fmus"]["plant"] = {"hardware": "emulator_pty"}
    doc["events"] = [e for e in doc["events"] if e["time"] < duration]
    path = tmp / "hil.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--no-emulator", action="store_true")
    ap.add_argument("--rt-priority", type=int, help="run the loop at this SCHED_FIFO priority (root)")
    args = ap.parse_args()
    sc = load_scenario("minerva2_dp")
    for inst in sc.instances:
        build_fmu(sc.vessel, inst.kind or "")
    sc = dataclasses.replace(
        sc, duration=args.duration, events=[e for e in sc.events if e[0] < args.duration]
    )
    print(
        f"minerva2_dp, {args.duration:g} s in real time, step {sc.step * 1e3:g} ms; "
        f"{platform.machine()}, Python {platform.python_version()}"
    )
    if args.rt_priority:
        granted = Pacer.elevate(args.rt_priority)
        print(f"SCHED_FIFO priority {args.rt_priority}: {'on' if granted else 'refused'}")
    if args.no_emulator:
        result = run(dataclasses.replace(sc, realtime=True), progress=False)
        what = "simulated plant, paced"
    else:
        profile = load_profile("emulator_pty")
        with tempfile.TemporaryDirectory() as tmp:
            hil = load_scenario(_hil_scenario(Path(tmp), args.duration))
            proc = subprocess.Popen(
                [sys.executable, "-m", "seafmu.emulate", "minerva2",
                 "--serial", f"pty:{profile.serial.url}", "--can", f"slcan:pty:{profile.can.channel}",
                 "--scenario", "minerva2_dp"],
                cwd=REPO, stdout=subprocess.PIPE, text=True,
            )
            try:
                assert proc.stdout is not None
                proc.stdout.readline()  # READY ...
                result = run(hil, progress=False, record_dir=Path(tmp) / "rec")
            finally:
                proc.terminate()
                proc.wait(timeout=10)
        what = "hardware link <-> emulator process (NMEA serial + SLCAN on ptys)"
        drops = {k: int(result.signals[f"plant.{k}"][-1])
                 for k in ("lines_dropped", "frames_dropped", "port_losses")}
        alarms = int(result.signals["plant.watchdog_alarm"].max())
        print(f"link: watchdog alarm {'raised' if alarms else 'never raised'}, dropped/lost: {drops}")
    assert result.pacing is not None
    stats = PacingStats(**result.pacing)
    w = stats.window_factors
    print(f"{what}:")
    print(
        f"  real-time factor   {stats.realtime_factor:.4f} over {stats.wall_time:.2f} s wall "
        f"(goal 1.00 +- 0.01); {stats.window:g} s windows: "
        + (f"{min(w):.4f} .. {max(w):.4f}" if w else "none (run shorter than one window)")
    )
    print(
        f"  step jitter        p50 {1e3 * stats.jitter_p50:.3f} ms, p99 {1e3 * stats.jitter_p99:.3f} ms "
        f"(goal < 5 ms), max {1e3 * stats.jitter_max:.3f} ms; "
        f"{stats.overruns} overruns in {stats.steps} steps"
    )


if __name__ == "__main__":
    main()
