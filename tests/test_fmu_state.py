"""FMU state (issue 8): get/set and serialise/deserialise continue bit-identically for every FMU
(two vessels x four kinds), and serialised states are plain data that can run no code: foreign,
other-FMU, other-version, corrupt and ill-fitting states are refused with one logged line, and
the FMU goes on as if nothing happened."""

from __future__ import annotations

import ctypes
import dataclasses
import hashlib
import json
import pickle
import struct
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi1 import FMICallException
from fmpy.fmi2 import (
    FMU2Slave,
    fmi2CallbackAllocateMemoryTYPE,
    fmi2CallbackFreeMemoryTYPE,
    fmi2CallbackFunctions,
    fmi2CallbackLoggerTYPE,
)
from fmpy.logging import addLoggerProxy

from seafmu.build import KINDS
from seafmu.components.block import full_params
from seafmu.components.state import StateError, capture, restore
from seafmu.components.vessel_spec import load_vessel
from seafmu.fmus import _state
from seafmu.fmus.registry import BLOCKS
from seafmu.master import run
from seafmu.scenario import load_scenario

SCENARIOS = {"minerva2": "minerva2_dp", "amv_osf": "amv_osf_autopilot"}
DURATION = 40.0
K_SAVE, N_CMP = 500, 120  # save the state at step 500 (25 s, past the first events), compare 120 steps


@pytest.fixture(scope="module")
def recorded() -> dict[str, tuple]:
    """Per vessel: the scenario (shortened) and every signal of its in-process run."""
    out = {}
    for vessel, name in SCENARIOS.items():
        sc = load_scenario(name)
        sc = dataclasses.replace(sc, duration=DURATION, record_every=1,
                                 events=[e for e in sc.events if e[0] <= DURATION])
        out[vessel] = (sc, run(sc, mode="inprocess", progress=False).signals)
    return out


_LOGS: dict[str, list[tuple[int, str]]] = {}  # instance name -> (status, message)
_CB: list[fmi2CallbackFunctions] = []


def _route(env: object, instance: bytes, status: int, category: bytes, message: bytes) -> None:
    _LOGS.setdefault((instance or b"").decode(), []).append((status, (message or b"").decode()))


def _callbacks() -> fmi2CallbackFunctions:
    """One set of callbacks for the process: fmpy's logger proxy keeps a single Python callback,
    so a callback per instance would leave the proxy pointing at freed ones."""
    if not _CB:
        cb = fmi2CallbackFunctions()
        cb.logger = fmi2CallbackLoggerTYPE(_route)
        libc = ctypes.CDLL(None)
        cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(libc.calloc)
        cb.freeMemory = fmi2CallbackFreeMemoryTYPE(libc.free)
        addLoggerProxy(ctypes.byref(cb))
        _CB.append(cb)
    return _CB[0]


class _Host:
    """One FMU instance on fmpy with its log, driven with recorded inputs."""

    def __init__(self, path: Path, params: dict, inputs: dict[str, np.ndarray]) -> None:
        name = f"s{len(_LOGS)}"
        self.log = _LOGS.setdefault(name, [])
        self.md = read_model_description(str(path))
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.out = [v.valueReference for v in self.md.modelVariables if v.causality == "output"]
        self.in_vr = [self.vars[n].valueReference for n in inputs]
        self.inputs = np.column_stack(list(inputs.values())) if inputs else None
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=extract(str(path)),
                             modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=name)
        self.fmu.instantiate(callbacks=_callbacks(), loggingOn=True)
        self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        for k, v in params.items():
            var = self.vars[k]
            setter = {"Real": self.fmu.setReal, "Integer": self.fmu.setInteger, "String": self.fmu.setString}
            setter[var.type]([var.valueReference], [v])
        if self.inputs is not None:
            self.fmu.setReal(self.in_vr, self.inputs[0].tolist())
        self.fmu.exitInitializationMode()

    def errors(self) -> list[str]:
        return [m for s, m in self.log if s == 3]

    def outputs(self) -> np.ndarray:
        return np.array(self.fmu.getReal(self.out))

    def advance(self, k0: int, k1: int, h: float) -> np.ndarray:
        rows = []
        for k in range(k0, k1):
            if self.inputs is not None:
                self.fmu.setReal(self.in_vr, self.inputs[min(k, len(self.inputs) - 1)].tolist())
            self.fmu.doStep(k * h, h)
            rows.append(self.outputs())
        return np.array(rows)

    def close(self) -> None:
        self.fmu.terminate()
        self.fmu.fmi2FreeInstance(self.fmu.component)


def _host(built: dict, recorded: dict, vessel: str, kind: str, defaults: bool = False) -> tuple[_Host, float]:
    sc, sig = recorded[vessel]
    inst = sc.instance(kind)
    conns = {dv: sig[f"{si}.{sv}"] for si, sv, di, dv in sc.connections if di == inst.name}
    md = read_model_description(str(built[(vessel, kind)]))
    for v in md.modelVariables:  # inputs set by events (setpoints) as the run recorded them
        if v.causality == "input" and v.name not in conns and f"{inst.name}.{v.name}" in sig:
            conns[v.name] = sig[f"{inst.name}.{v.name}"]
    params = {} if defaults else dict(inst.parameters)
    return _Host(built[(vessel, kind)], params, conns), sc.step * inst.step_multiple


@pytest.mark.parametrize("vessel", list(SCENARIOS))
@pytest.mark.parametrize("kind", KINDS)
def test_state_round_trips_are_bit_identical(built_fmus: dict, recorded: dict, vessel: str,
                                             kind: str) -> None:
    """get/set, serialise/deserialise into the same instance, and deserialise into a second
    instance made with default parameters: all continue exactly like the uninterrupted run."""
    a, h = _host(built_fmus, recorded, vessel, kind)
    a.advance(0, K_SAVE, h)
    at_save = a.outputs()
    state = a.fmu.getFMUstate()
    blob = bytes(a.fmu.serializeFMUstate(state))
    assert blob == bytes(a.fmu.serializeFMUstate(state))  # deterministic (asked twice by the wrapper)
    first = a.advance(K_SAVE, K_SAVE + N_CMP, h)
    assert np.ptp(first, axis=0).max() > 0  # the compared stretch is not a constant

    a.fmu.setFMUstate(state)
    np.testing.assert_array_equal(a.outputs(), at_save)
    np.testing.assert_array_equal(a.advance(K_SAVE, K_SAVE + N_CMP, h), first)
    a.fmu.setFMUstate(state)  # a state can be set more than once
    np.testing.assert_array_equal(a.advance(K_SAVE, K_SAVE + N_CMP, h), first)

    restored = a.fmu.deSerializeFMUstate(blob)
    a.fmu.setFMUstate(restored)
    np.testing.assert_array_equal(a.advance(K_SAVE, K_SAVE + N_CMP, h), first)

    b, _ = _host(built_fmus, recorded, vessel, kind, defaults=True)  # never stepped, other parameters
    other = b.fmu.deSerializeFMUstate(blob)
    b.fmu.setFMUstate(other)
    np.testing.assert_array_equal(b.outputs(), at_save)
    np.testing.assert_array_equal(b.advance(K_SAVE, K_SAVE + N_CMP, h), first)
    for s, f in ((state, a), (restored, a), (other, b)):
        f.fmu.freeFMUstate(s)
    assert a.errors() == [] and b.errors() == []
    a.close()
    b.close()


def test_state_header_names_format_version_and_guid(built_fmus: dict, recorded: dict) -> None:
    a, h = _host(built_fmus, recorded, "minerva2", "controller")
    a.advance(0, 10, h)
    blob = bytes(a.fmu.serializeFMUstate(a.fmu.getFMUstate()))
    magic, version, n = struct.unpack_from(">8sHB", blob)
    assert (magic, version) == (b"SEAFMUST", 1)
    assert blob[11 : 11 + n].decode() == a.md.guid
    assert b"pickle" not in blob and not blob[11 + n + 40 :].startswith(b"\x80")  # JSON, not pickle
    json.loads(blob[11 + n + 40 :])
    a.close()


def _with_checksum(head_and_payload: tuple[bytes, bytes]) -> bytes:
    head, payload = head_and_payload
    return head + hashlib.sha256(head + payload).digest() + payload


def _split(blob: bytes) -> tuple[bytes, bytes]:
    n = blob[10]
    return blob[: 19 + n], blob[51 + n :]


def _reencoded(blob: bytes, guid: str, change: Callable[[dict], None]) -> bytes:
    tree = _state.decode(blob, guid)
    change(tree)
    return _state.encode(tree, guid)


def _find(node: object, kind: str) -> dict:
    """The first marker dict of the given kind in a tree."""
    if isinstance(node, dict):
        if node.get("$t") == kind:
            return node
        children = list(node.values())
    elif isinstance(node, list):
        children = node
    else:
        children = []
    for c in children:
        found = _find(c, kind)
        if found:
            return found
    return {}


def test_foreign_other_and_corrupt_states_are_refused_and_change_nothing(built_fmus: dict, recorded: dict,
                                                                         tmp_path: Path) -> None:
    a, h = _host(built_fmus, recorded, "minerva2", "plant")
    ref, _ = _host(built_fmus, recorded, "minerva2", "plant")  # the undisturbed twin
    a.advance(0, 100, h)
    ref.advance(0, 100, h)
    blob = bytes(a.fmu.serializeFMUstate(a.fmu.getFMUstate()))
    guid = a.md.guid

    marker = tmp_path / "payload_ran"

    class Payload:
        def __reduce__(self) -> tuple:
            return (open, (str(marker), "w"))

    def other_fmu(vessel: str, kind: str) -> bytes:
        o, _ = _host(built_fmus, recorded, vessel, kind)
        data = bytes(o.fmu.serializeFMUstate(o.fmu.getFMUstate()))
        o.close()
        return data

    head, payload = _split(blob)
    v2 = head[:8] + struct.pack(">H", 2) + head[10:]
    flipped = bytearray(blob)
    flipped[-10] ^= 0x01
    refused = {
        "pickle": (pickle.dumps(Payload()), "not a seafmu FMU state"),
        "empty": (b"", "not a seafmu FMU state"),
        "controller state": (other_fmu("minerva2", "controller"), "state of another FMU"),
        "other vessel's plant": (other_fmu("amv_osf", "plant"), "state of another FMU"),
        "version 2": (_with_checksum((v2, payload)), "format version 2"),
        "flipped bit": (bytes(flipped), "checksum mismatch"),
        "truncated": (blob[:-7], "the header says"),
        "object dtype": (_with_checksum((head, payload.replace(b'"<f8"', b'"|O8"', 1))), "dtype"),
    }
    for what, (data, why) in refused.items():
        # two instances of this FMU live here, and the wrapper calls the deserialiser on the class:
        # the bytes are taken as a rejected state, which fmi2SetFMUstate (an instance call) refuses
        state = a.fmu.deSerializeFMUstate(data)
        with pytest.raises(FMICallException) as err:
            a.fmu.setFMUstate(state)
        assert err.value.status == 4, what
        assert why in a.errors()[-1] and "\n" not in a.errors()[-1], (what, a.errors()[-1])
        a.fmu.freeFMUstate(state)
    assert not marker.exists()
    ref.close()  # alone now: fmi2DeSerializeFMUstate itself refuses, one line at error level
    for what, (data, why) in refused.items():
        with pytest.raises(FMICallException) as err:
            a.fmu.deSerializeFMUstate(data)
        assert err.value.status == 4, what
        assert why in a.errors()[-1] and "\n" not in a.errors()[-1], (what, a.errors()[-1])
    assert not marker.exists()
    ref, _ = _host(built_fmus, recorded, "minerva2", "plant")
    ref.advance(0, 100, h)

    # well-formed bytes of this FMU whose content does not fit: refused by fmi2SetFMUstate
    def bad_class(tree: dict) -> None:
        _find(tree["block"]["attrs"], "obj")["class"] = "os.system"  # a helper object inside

    def bad_shape(tree: dict) -> None:
        nd = _find(tree["block"], "nd")
        nd["value"] = np.zeros(nd["value"].size + 1)

    def bad_rng(tree: dict) -> None:
        _find(tree["block"], "rng")["bit_generator"] = "Pickled"

    for what, change, why in (("class", bad_class, "os.system"),
                              ("shape", bad_shape, "does not fit"),
                              ("rng", bad_rng, "unknown bit generator")):
        state = a.fmu.deSerializeFMUstate(_reencoded(blob, guid, change))
        with pytest.raises(FMICallException):
            a.fmu.setFMUstate(state)
        assert why in a.errors()[-1], (what, a.errors()[-1])
        a.fmu.freeFMUstate(state)

    # nothing of that reached the model: it goes on exactly like its twin
    np.testing.assert_array_equal(a.advance(100, 160, h), ref.advance(100, 160, h))
    a.close()
    ref.close()


def test_the_issue_repro_payload_does_not_run(built_fmus: dict, tmp_path: Path) -> None:
    """../shared/repro/fmu_state_pickle.py, in a child process: 'payload ran: False'."""
    import subprocess
    import sys
    import textwrap

    code = textwrap.dedent('''
        import os, pickle, sys
        from fmpy import extract, read_model_description
        from fmpy.fmi2 import FMU2Slave
        marker = sys.argv[2]
        class Payload:
            def __reduce__(self):
                return (open, (marker, "w"))
        md = read_model_description(sys.argv[1])
        fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(sys.argv[1]),
                        modelIdentifier=md.coSimulation.modelIdentifier, instanceName="x")
        fmu.instantiate()
        fmu.setupExperiment(startTime=0)
        fmu.enterInitializationMode()
        fmu.exitInitializationMode()
        try:
            fmu.deSerializeFMUstate(pickle.dumps(Payload()))
            print("accepted")
        except Exception as e:
            print("refused:", e)
        print("payload ran:", os.path.exists(marker))
    ''')
    marker = tmp_path / "ran"
    p = subprocess.run([sys.executable, "-c", code, str(built_fmus[("minerva2", "controller")]), str(marker)],
                       capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr[-2000:]
    assert "payload ran: False" in p.stdout and "refused" in p.stdout


def test_state_before_initialisation_round_trips(built_fmus: dict) -> None:
    """A state taken in initialisation mode (no block yet) is restored as such."""
    path = built_fmus[("amv_osf", "allocator")]
    md = read_model_description(str(path))
    out = [v.valueReference for v in md.modelVariables if v.causality == "output"]
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="i")
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    early = fmu.deSerializeFMUstate(fmu.serializeFMUstate(fmu.getFMUstate()))

    def run_a_bit() -> list[float]:
        fmu.exitInitializationMode()
        for k in range(5):
            fmu.doStep(k * 0.1, 0.1)
        return fmu.getReal(out)

    first = run_a_bit()
    fmu.setFMUstate(early)
    with pytest.raises(FMICallException):  # back in initialisation mode: no block to step yet
        fmu.doStep(0.5, 0.1)
    assert run_a_bit() == first
    fmu.freeFMUstate(early)
    fmu.terminate()
    fmu.fmi2FreeInstance(fmu.component)


# -- components.state: the block tree as plain data ---------------------------------------------

BLOCK_SCENARIOS = ["minerva2_lawnmower", "minerva2_sensor_faults", "minerva2_thruster_failure",
                   "minerva2_dp_waves", "amv_osf_land_water"]


@pytest.mark.parametrize("name", BLOCK_SCENARIOS)
def test_block_state_through_bytes_into_a_fresh_block(name: str) -> None:
    """Objects a block creates during the run (guidance, land model, QP solver, fault streams)
    come back through the bytes, into a block that never ran."""
    sc = load_scenario(name)
    dur = min(sc.duration, 60.0)
    sc = dataclasses.replace(sc, duration=dur, record_every=1, events=[e for e in sc.events if e[0] <= dur])
    sig = run(sc, mode="inprocess", progress=False).signals
    n = len(sig["time"]) if "time" in sig else len(next(iter(sig.values())))
    for inst in sc.instances:
        if inst.kind not in BLOCKS:
            continue
        vessel = load_vessel(sc.vessel)
        iface = BLOCKS[inst.kind].interface(vessel)
        names = iface.input_names()
        params = full_params(iface, {k: v for k, v in inst.parameters.items()
                                     if k in {p.name for p in iface.parameters}})
        u = np.tile([float(s.start) for s in iface.inputs], (n, 1))
        for i, nm in enumerate(names):
            if nm in inst.parameters:
                u[:, i] = float(inst.parameters[nm])
            if f"{inst.name}.{nm}" in sig:
                u[:, i] = sig[f"{inst.name}.{nm}"]
        for si, sv, di, dv in sc.connections:
            if di == inst.name:
                u[:, names.index(dv)] = sig[f"{si}.{sv}"]
        h = sc.step * inst.step_multiple
        steps = min(n - 1, round(dur / h))
        k_save = (2 * steps) // 3
        block = BLOCKS[inst.kind](vessel, params)
        block.start(u[0])

        def advance(b: object, k0: int, k1: int, h: float = h, u: np.ndarray = u) -> np.ndarray:
            return np.array([b.step(k * h, h, u[min(k, n - 1)]) for k in range(k0, k1)])  # type: ignore[attr-defined]

        advance(block, 0, k_save)
        blob = _state.encode(block.export_state(), "g")
        first = advance(block, k_save, k_save + 40)
        fresh = BLOCKS[inst.kind](vessel, params)
        fresh.start(u[0])
        fresh.import_state(_state.decode(blob, "g"))
        again = advance(fresh, k_save, k_save + 40)
        np.testing.assert_array_equal(again, first, err_msg=f"{name}/{inst.name}")


class _Helper:
    pass


def test_capture_refuses_what_is_not_data_and_restore_is_all_or_nothing(minerva: object) -> None:
    block = BLOCKS["controller"](minerva, full_params(BLOCKS["controller"].interface(minerva), {}))
    u = np.zeros(len(BLOCKS["controller"].interface(minerva).inputs))
    block.start(u)
    block.step(0.0, 0.05, u)
    block._probe = print  # type: ignore[attr-defined]
    with pytest.raises(StateError, match=r"\._probe: builtins\.builtin_function"):
        capture(block)
    block._probe = _Helper()  # type: ignore[attr-defined]  # not a components class
    with pytest.raises(StateError, match="is not state data"):
        capture(block)
    del block._probe  # type: ignore[attr-defined]

    tree = capture(block)
    block.step(0.05, 0.05, u + 1.0)  # the block moves on after the capture
    now = _state.encode(capture(block), "g")
    bad = capture(block)
    bad["attrs"]["_y"] = {"$t": "nd", "id": 10**6, "value": np.zeros(3)}  # wrong shape
    with pytest.raises(StateError, match="does not fit"):
        restore(block, bad)
    assert _state.encode(capture(block), "g") == now  # untouched
    restore(block, tree)
    assert _state.encode(capture(block), "g") == _state.encode(tree, "g")
    del tree["attrs"]["_y"]  # an attribute the state does not have is removed from the block
    restore(block, tree)
    assert not hasattr(block, "_y")
