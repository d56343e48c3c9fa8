"""The master: step multiples, event timing, recording, explicit connections."""

from __future__ import annotations

import dataclasses

import numpy as np

from seafmu.master import run
from seafmu.scenario import load_scenario


def _short(name: str, duration: float = 60.0):
    sc = load_scenario(name)
    return dataclasses.replace(sc, duration=duration, events=[e for e in sc.events if e[0] <= duration])


def test_step_multiples_step_each_fmu_at_its_own_rate(built_fmus: dict) -> None:
    sc = _short("minerva2_dp")
    insts = [dataclasses.replace(i, step_multiple=2) if i.name in ("observer", "controller") else i
             for i in sc.instances]
    r = run(dataclasses.replace(sc, instances=insts, record_every=1), progress=False)
    n = round(sc.duration / sc.step)
    assert r.steps == {"plant": n, "observer": n // 2, "controller": n // 2, "allocator": n}
    # The controller output is held between its steps: it changes only every second master step.
    tau = r.signals["controller.tau_X"]
    changes = np.flatnonzero(np.diff(tau[200:260]))
    assert len(changes) >= 29 and np.all(np.diff(changes) == 2)
    # and the loop still does its job: north setpoint of 3 m at 40 s is approached
    assert abs(r.signals["plant.north"][-1] - 3.0) < 0.5


def test_events_apply_at_their_time(built_fmus: dict) -> None:
    r = run(_short("minerva2_dp"), mode="inprocess", progress=False)
    ref = r.signals["controller.north_ref"]
    t = r.time
    assert np.all(ref[t < 40 - 1e-9] == 0.0) and np.all(ref[t >= 40 + 0.1 - 1e-9] == 3.0)
    # the reference model starts moving right after the step, not before
    nd = r.signals["controller.north_d"]
    assert abs(nd[np.searchsorted(t, 39.9)]) < 0.05 and nd[np.searchsorted(t, 45.0)] > 0.2


def test_record_interval_and_time_axis(built_fmus: dict) -> None:
    sc = _short("minerva2_dp", 10.0)
    r = run(sc, mode="inprocess", progress=False)
    assert sc.record_every == 2
    np.testing.assert_allclose(r.time, np.arange(0, 10.0 + 1e-9, 0.1), atol=1e-12)
    assert all(len(v) == len(r.time) for v in r.signals.values())


def test_explicit_connections_override_name_matching(built_fmus: dict, tmp_path) -> None:
    """Cut the observer out of the loop: the controller reads the plant's true state directly."""
    names = ["north", "east", "down", "roll", "pitch", "yaw", "u", "v", "w", "p", "q", "r"]
    lines = "\n".join(f"  - plant.{n} -> controller.{n}_hat" for n in names)
    path = tmp_path / "truth.yaml"
    path.write_text(
        "name: truth_feedback\nvessel: minerva2\nduration: 60\nstep: 0.05\n"
        "fmus:\n  plant: {kind: plant, parameters: {down_0: 5}}\n  controller: {kind: controller,"
        " parameters: {down_ref: 5}}\n  allocator: {kind: allocator}\n"
        f"connections:\n{lines}\n"
        "events:\n  - {time: 10, set: controller.north_ref, value: 2}\n"
        "checks:\n  - {signal: plant.north, metric: final_abs, max: 10}\n"
    )
    sc = load_scenario(path)
    assert ("plant", "north", "controller", "north_hat") in sc.connections
    r = run(sc, progress=False)
    assert abs(r.signals["plant.north"][-1] - 2.0) < 0.1


def test_a_slow_fmu_publishes_its_outputs_at_the_right_time(built_fmus: dict, tmp_path) -> None:
    """A plant stepping every 2 master steps shows its t + 2h state at t + 2h, never earlier."""
    def scenario(step: float, mult: int):
        path = tmp_path / f"s{mult}.yaml"
        path.write_text(
            f"name: slow\nvessel: amv_osf\nduration: 4\nstep: {step}\n"
            f"fmus: {{plant: {{kind: plant, step_multiple: {mult}, parameters: {{noise_scale: 0}}}}}}\n"
            "events: [{time: 0, set: plant.n_cmd_1, value: 1.5}, {time: 0, set: plant.n_cmd_2, value: 1.0}]\n"
        )
        return load_scenario(path)

    slow = run(scenario(0.05, 2), progress=False)
    ref = run(scenario(0.1, 1), progress=False)
    north = slow.signals["plant.north"]
    np.testing.assert_allclose(north[2::2], ref.signals["plant.north"][1:], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(north[1::2], north[0:-1:2])  # held between its steps
    assert ref.signals["plant.north"][-1] > 0.5


def test_units_come_from_the_kind_registry_and_declare_pacing(monkeypatch) -> None:
    """seafmu/unit.py: the master builds every unit through UNIT_KINDS (no if/else on the kind) and
    asks a unit whether it paces the loop (``paces_itself``), never guesses from its attributes."""
    from seafmu import unit
    from seafmu.hardware.link import HardwareLink
    from seafmu.master import BlockUnit, FmuUnit

    assert {"fmu", "inprocess", "hardware"} <= set(unit.UNIT_KINDS)
    assert BlockUnit.paces_itself is False and FmuUnit.paces_itself is False
    assert unit.run_errors({"hardware"})[0].__name__ == "HardwareError" and unit.run_errors({"fmu"}) == ()

    made: list[tuple[str, list[str]]] = []
    block = unit.UNIT_KINDS["inprocess"]

    def counting(req: unit.UnitRequest) -> unit.Unit:
        u = block.make(req)
        made.append((req.instance.name, req.in_names))
        return u

    monkeypatch.setitem(unit.UNIT_KINDS, "inprocess", dataclasses.replace(block, make=counting))
    sc = _short("minerva2_dp", 1.0)
    r = run(sc, mode="inprocess", progress=False)
    assert [n for n, _ in made] == [i.name for i in sc.instances] and r.pacing is None
    assert dict(made)["plant"] and all(n.startswith("n_cmd_") for n in dict(made)["plant"])

    class Paced:  # a unit that declares pacing
        paces_itself = True

    assert unit.is_paced(Paced()) and not unit.is_paced(BlockUnit.__new__(BlockUnit))
    assert callable(HardwareLink.pacing_stats)  # the link paces itself (pace=True) and reports how well
    try:
        unit.make_unit("nope", None)  # type: ignore[arg-type]
    except ValueError as exc:
        assert "unknown unit kind 'nope'" in str(exc)
    else:
        raise AssertionError("an unknown kind must be refused")


def test_every_unit_class_offers_the_whole_unit_protocol() -> None:
    """The master asks units (never their class) to hand over logs and name their errors."""
    import inspect

    from seafmu.hardware.link import HardwareLink
    from seafmu.master import BlockUnit, FmuUnit
    from seafmu.unit import Unit

    wanted = {n for n, v in vars(Unit).items() if inspect.isfunction(v) and not n.startswith("_")}
    assert {"collect_log", "step_error", "do_step", "terminate"} <= wanted
    for cls in (BlockUnit, FmuUnit, HardwareLink):
        missing = sorted(n for n in wanted if not callable(getattr(cls, n, None)))
        assert not missing, (cls.__name__, missing)
    exc = ValueError("x")
    assert BlockUnit.step_error(BlockUnit.__new__(BlockUnit), "step", exc) is exc


class _StopAfter:
    """A stop request that turns on after ``n`` master steps (the loop reads ``signum`` once a step)."""

    def __init__(self, n: int) -> None:
        self.reads, self.n = 0, n

    @property
    def signum(self) -> int | None:
        self.reads += 1
        return 15 if self.reads > self.n else None

    name = "SIGTERM"


def test_fmus_read_only_connected_outputs_between_records_yet_record_every_output(built_fmus: dict) -> None:
    """Steps that are not recorded read only the connected outputs of an FMU; the recorded rows,
    including the last one of a run stopped between two samples, hold every output of that step,
    as the in-process composition (which reads all outputs every step) records them."""
    sc = dataclasses.replace(_short("minerva2_dp", 2.0), record_every=2)
    for steps in (7, 40):  # stopped between two samples (odd), or not
        fmu = run(sc, mode="fmu", progress=False, stop=_StopAfter(steps))  # type: ignore[arg-type]
        ref = run(sc, mode="inprocess", progress=False, stop=_StopAfter(steps))  # type: ignore[arg-type]
        assert fmu.time[-1] == ref.time[-1] == steps * sc.step
        for k in ref.signals:
            np.testing.assert_allclose(fmu.signals[k], ref.signals[k], rtol=0, atol=1e-9, err_msg=k)
        assert ref.signals["plant.sog"][-1] != ref.signals["plant.sog"][-2]  # not connected, moving
