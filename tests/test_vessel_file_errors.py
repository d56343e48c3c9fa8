"""Malformed vessel files: unknown keys, YAML 1.1 numbers and physically impossible thrusters or
magnitudes each fail on load with one line naming the file and the field."""

from __future__ import annotations

import re
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
import yaml

from seafmu.components.vessel_spec import (
    VESSEL_DIR,
    VesselFileError,
    VesselSpec,
    _document,
    bundled_vessels,
    load_vessel,
)


def _variant(tmp_path: Path, base: str, edit: Callable[[dict], object]) -> VesselSpec:
    doc = yaml.safe_load((VESSEL_DIR / f"{base}.yaml").read_text())
    edit(doc)
    p = tmp_path / f"{base}_variant.yaml"
    p.write_text(yaml.safe_dump(doc, sort_keys=False))
    return load_vessel(p)


def _fails(tmp_path: Path, base: str, edit: Callable[[dict], object], message: str) -> str:
    with pytest.raises(VesselFileError) as err:
        _variant(tmp_path, base, edit)
    text = str(err.value)
    assert "\n" not in text and text.startswith(str(tmp_path))
    assert message in text, text
    return text


def _rename(node: dict, old: str, new: str) -> None:
    node[new] = node.pop(old)


def _unit(doc: dict, i: int = 0) -> dict:
    return doc["thrusters"]["units"][i]


@pytest.mark.parametrize("base, edit, message", [
    ("supply", lambda d: _rename(d, "current_inertia", "current_inertial"),
     "field 'current_inertial': unknown field; did you mean 'current_inertia'?"),
    ("minerva2", lambda d: d.update(inertia="asymmetric"),
     "field 'inertia': must be one of symmetric, published, got 'asymmetric'"),
    ("minerva2", lambda d: _rename(d, "mass_matrix", "mass_matirx"),
     "field 'mass_matirx': unknown field; did you mean 'mass_matrix'?"),
    ("minerva2", lambda d: d["sensors"][0].update(bais={"value": [0.1, 0.1], "source": "x"}),
     "field 'sensors[0].bais': unknown field; did you mean 'bias'?"),
    ("minerva2", lambda d: _unit(d, 2).update(time_constnat={"value": 1.0, "source": "x"}),
     "field 'thrusters.units[2].time_constnat': unknown field; did you mean 'time_constant'?"),
    ("minerva2", lambda d: d["thrusters"].update(laws="linear"),
     "field 'thrusters.laws': unknown field; did you mean 'law'?"),
    ("minerva2", lambda d: d["thrusters"].update(count=7),
     "field 'thrusters.count': unknown field (known: law, units)"),
    ("minerva2", lambda d: _rename(d["restoring"], "buoyancy", "bouyancy"),
     "field 'restoring.bouyancy': unknown field; did you mean 'buoyancy'?"),
    ("minerva2", lambda d: d["mass_matrix"].update(sorce="typo"),
     "field 'mass_matrix.sorce': unknown field; did you mean 'source'?"),
    ("minerva2", lambda d: d["mass_matrix"].update(unit="t"),
     "field 'mass_matrix.unit': unknown field (known: value, source)"),
    ("minerva2", lambda d: _rename(d["added_mass"], "value", "valeu"),
     "field 'added_mass.valeu': unknown field; did you mean 'value'?"),
    ("minerva2", lambda d: d.update(notes="free text"),
     "field 'notes': unknown field (known: name, title, dof"),
    ("amv_osf", lambda d: d.update(restoring={"weight": 1.0}),
     "field 'restoring': a 3-DOF model (surge, sway, yaw) has no restoring forces"),
    ("amv_osf", lambda d: _rename(d["extra"]["land"], "pitch", "pich"),
     "field 'extra.land.pich': unknown field; did you mean 'pitch'?"),
    ("amv_osf", lambda d: d["extra"].update(lands={}),
     "field 'extra.lands': unknown field; did you mean 'land'?"),
    ("amv_osf", lambda d: d["extra"]["land"]["pitch"].update(unit="cm"),
     "field 'extra.land.pitch.unit': unknown field (known: value, source)"),
    ("amv_osf", lambda d: d["extra"]["land"]["on_the_spot_rotation"].update(value=True),
     "field 'extra.land.on_the_spot_rotation': must be false"),
    ("amv_osf", lambda d: d["gnc"].update(alocator="two_screw"),
     "unknown field(s) alocator; known: controller, allocator, guidance, camera_thrusters, tuning; did you "
     "mean 'allocator'?"),
    ("minerva2", lambda d: d.update(sensors={"gnss": {}}), "field 'sensors': expected a list of sensors"),
    ("minerva2", lambda d: d["thrusters"]["units"].append("spare"),
     "field 'thrusters.units[7]': expected a mapping of name, position"),
])
def test_unknown_keys_are_refused_with_a_hint(tmp_path: Path, base: str, edit, message: str) -> None:
    _fails(tmp_path, base, edit, message)


def test_yaml11_numbers_in_a_vessel_file(tmp_path: Path) -> None:
    text = (VESSEL_DIR / "minerva2.yaml").read_text()
    assert "rate_hz: {value: 10.0," in text
    p = tmp_path / "v.yaml"
    for given, message in (("0x10", "expected a number, got '0x10'"), ("1_0", "expected a number, got '1_0'"),
                           ("1:30", "expected a number, got '1:30'"), ('"10"', "expected a number, got '10'"),
                           ("true", "expected a number, got True")):
        p.write_text(text.replace("rate_hz: {value: 10.0,", f"rate_hz: {{value: {given},", 1))
        with pytest.raises(VesselFileError, match=re.escape(message)):
            load_vessel(p)
    p.write_text(text.replace("rate_hz: {value: 10.0,", "rate_hz: {value: 010,", 1))
    assert 10.0 in [s.rate_hz for s in load_vessel(p).sensors]  # decimal 10, not octal 8
    with pytest.raises(VesselFileError, match=r"field 'linear_damping': expected numbers"):
        p.write_text(text.replace("value: [", "value: [1_0, ", 1))
        load_vessel(p)
    p.write_text(text.replace("rate_hz: {value: 10.0,", "rate_hz: {value: !!int 0x10,", 1))
    with pytest.raises(VesselFileError, match=re.escape("not valid YAML ('0x10' is not a decimal integer)")):
        load_vessel(p)
    p.write_text(text.replace("rate_hz: {value: 10.0,", f"rate_hz: {{value: {'9' * 5000},", 1))
    with pytest.raises(VesselFileError, match="not valid YAML"):
        load_vessel(p)


@pytest.mark.parametrize("base, edit, message", [
    ("minerva2", lambda d: _unit(d)["direction"].update(value=[0, 0, 0]),
     "field 'thrusters.units[0].direction': must be a non-zero vector"),
    ("minerva2", lambda d: _unit(d)["direction"].update(value=[1e-9, 0, 0]),
     "field 'thrusters.units[0].direction': must be a non-zero vector (length 1e-09)"),
    ("amv_osf", lambda d: _unit(d, 1)["direction"].update(value=[0, 0, 1]),
     "field 'thrusters.units[1].direction': [0.0, 0.0, 1.0] has no horizontal component"),
    ("minerva2", lambda d: _unit(d)["k_forward"].update(value=0), "k_forward': must be positive, got 0.0"),
    ("minerva2", lambda d: _unit(d)["k_reverse"].update(value=-1), "k_reverse': must be positive, got -1.0"),
    ("minerva2", lambda d: _unit(d)["n_max"].update(value=0), "n_max': must be positive, got 0.0"),
    ("minerva2", lambda d: _unit(d)["time_constant"].update(value=0), "time_constant': must be positive"),
    ("minerva2", lambda d: _unit(d)["position"].update(value=[float("nan"), 0, 0]),
     "field 'thrusters.units[0].position': must be finite"),
    ("minerva2", lambda d: _unit(d)["position"].update(value=[0, 2000, 0]),
     "position': [0.0, 2000.0, 0.0] m is more than 1000 m from the body origin"),
    ("minerva2", lambda d: _unit(d)["n_max"].update(value=5000), "n_max': 5000 rev/s is above 1000 rev/s"),
    ("minerva2", lambda d: _unit(d)["k_forward"].update(value=1e300),
     "field 'thrusters.units[0].k_forward': 1e+300 is beyond any vessel's (|value| <= 1e+15 in SI units)"),
    ("minerva2", lambda d: _unit(d)["k_forward"].update(value=1e10),
     "field 'thrusters.units[0].k_forward': gives 4e+12 N at n_max; one thruster gives at most 1e+08 N"),
    ("supply", lambda d: _unit(d)["k_reverse"].update(value=1e6),  # N/rpm^2: 6.25e10 N at 250 rpm
     "field 'thrusters.units[0].k_reverse': gives 6.25e+10 N at n_max"),
    ("minerva2", lambda d: d["mass_matrix"].update(value=[1e300] * 6),
     "field 'mass_matrix': 1e+300 is beyond"),
    ("minerva2", lambda d: d["linear_damping"].update(value=[-1e16, 0, 0, 0, 0, 0]),
     "field 'linear_damping': -1e+16 is beyond"),
    ("minerva2", lambda d: d["restoring"]["weight"].update(value=1e20), "field 'restoring.weight': 1e+20 is"),
    ("amv_osf", lambda d: (d["mass_matrix"].update(value=[40, 40, 1e-12]),
                           d["added_mass"].update(value=[10, 51.4, 1e-12])),
     "total mass matrix is nearly singular"),
])
def test_impossible_values_are_refused(tmp_path: Path, base: str, edit, message: str) -> None:
    _fails(tmp_path, base, edit, message)


def test_the_largest_real_vessels_still_load(tmp_path: Path) -> None:
    """A VLCC's numbers (3e8 kg, yaw inertia with added mass ~5e12 kg m^2, 5 MN at 1.5 rev/s) pass."""
    def vlcc(d: dict) -> None:
        d["mass_matrix"].update(value=[3e8, 3e8, 5e12])
        d["added_mass"].update(value=[3e7, 2e8, 4e12])
        d["linear_damping"].update(value=[1e6, 1e7, 1e12])
        _unit(d, 4)["k_forward"] = {"value": 5e6 / 1.5**2, "source": "x"}
        _unit(d, 4)["n_max"] = {"value": 1.5, "source": "x"}
        _unit(d, 4)["position"].update(value=[-160.0, 0.0, 0.0])

    v = _variant(tmp_path, "supply", vlcc)
    assert v.M[2, 2] == 9e12 and v.thrusters.k_forward[4] * v.thrusters.n_max[4] ** 2 == pytest.approx(5e6)


@pytest.mark.parametrize("name", ["amv_osf", "minerva2", "minerva2_published_damping", "supply"])
def test_bundled_vessels_pass_every_check(name: str) -> None:
    assert name in bundled_vessels()
    v = load_vessel(name)
    assert np.all(np.linalg.norm(v.thrusters.directions, axis=1) > 0.1)


def test_a_folder_is_not_a_vessel_file(tmp_path: Path) -> None:
    folder = tmp_path / "vessels.yaml"
    folder.mkdir()
    for given in (folder, tmp_path, str(tmp_path)):
        with pytest.raises(VesselFileError, match=re.escape(f"{given}: is a folder, not a vessel file")):
            load_vessel(given)


def test_vessel_file_loads_fast() -> None:
    """Parsing with the YAML 1.2 resolvers stays on libyaml: a vessel file in a few milliseconds."""
    text = (VESSEL_DIR / "minerva2.yaml").read_bytes()
    best = float("inf")
    for i in range(5):
        t0 = time.perf_counter()
        _document(text + f"\n# {i}\n".encode())  # a new text each time: no cached document
        best = min(best, time.perf_counter() - t0)
    assert best < 0.05, best
