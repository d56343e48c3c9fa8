"""Codecs of the hardware link: NMEA 0183 sentences and CAN thruster frames (hypothesis properties)."""

from __future__ import annotations

import math

import can
import numpy as np
import pynmea2
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from seafmu.components.vessel_spec import load_vessel
from seafmu.hardware.canbus import CanFrameError, Command, Feedback, Nmea2000Codec, SeafmuCodec
from seafmu.hardware.nmea import SENTENCES, NmeaCodec, NmeaError, default_sentences
from seafmu.hardware.profile import HERE

N_MAX = np.array([20.0, 20.0, 20.0, 20.0, 20.0, 20.0, 2.3])
CODEC = NmeaCodec(63.44, 10.40)

angle = st.floats(-math.pi + 1e-6, math.pi, allow_nan=False)
small_rate = st.floats(-2.0, 2.0, allow_nan=False)
speed = st.floats(-10.0, 10.0, allow_nan=False)
values = st.fixed_dictionaries(
    {
        "north": st.floats(-5000.0, 5000.0),
        "east": st.floats(-5000.0, 5000.0),
        "down": st.floats(0.0, 6000.0),
        "roll": angle,
        "pitch": st.floats(-math.pi / 2, math.pi / 2),  # Euler pitch: beyond is implausible
        "yaw": angle,
        "u": speed,
        "v": speed,
        "w": speed,
        "p": small_rate,
        "q": small_rate,
        "r": small_rate,
        "course": angle,
        "sog": st.floats(0.0, 20.0),
    }
)
# half a unit in the last digit each sentence writes, in SI
TOL = {
    "north": 5e-4,
    "east": 5e-4,
    "down": 1e-4,
    "roll": 1e-6,
    "pitch": 1e-6,
    "yaw": 1e-6,
    "u": 1e-4,
    "v": 1e-4,
    "w": 1e-4,
    "p": 1e-6,
    "q": 1e-6,
    "r": 1e-6,
    "course": 1e-6,
    "sog": 1e-4,
}


def _angle_diff(a: float, b: float) -> float:
    return abs(math.remainder(a - b, 2 * math.pi))


@settings(max_examples=150, deadline=None)
@given(values, st.sampled_from(sorted(SENTENCES)))
def test_nmea_round_trip(v: dict[str, float], name: str) -> None:
    line = CODEC.encode(name, v)
    assert pynmea2.parse(line, check=True)  # a valid sentence with a correct checksum
    got_name, got = CODEC.decode(line)
    assert got_name == name
    expected = [c for c in (*SENTENCES[name].channels, *SENTENCES[name].extras)]
    assert sorted(got) == sorted(expected)
    for c, x in got.items():
        diff = _angle_diff(x, v[c]) if c in ("roll", "pitch", "yaw", "course") else abs(x - v[c])
        assert diff <= TOL[c], (name, c, v[c], x, line)


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=120))
def test_random_bytes_never_crash_the_nmea_decoder(data: bytes) -> None:
    text = data.decode("latin-1")
    try:
        CODEC.decode(text)
    except NmeaError as exc:
        assert exc.kind in ("checksum", "malformed", "invalid", "implausible", "unsupported")


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(sorted(SENTENCES)), values, st.integers(0, 200), st.binary(min_size=1, max_size=3))
def test_corrupted_sentences_are_rejected_not_misread(
    name: str, v: dict[str, float], pos: int, junk: bytes
) -> None:
    """A sentence with bytes changed either decodes to exactly what a valid sentence says or is dropped."""
    line = CODEC.encode(name, v)
    i = pos % len(line)
    bad = line[:i] + junk.decode("latin-1") + line[i + len(junk) :]
    try:
        CODEC.decode(bad)
    except NmeaError:
        return
    # only an undetectable change survives: the checksum still matches (XOR collisions exist)
    body, _, cs = bad.partition("*")
    assert f"{pynmea2.NMEASentence.checksum(body[1:]):02X}" == cs.strip().upper()[:2]


def test_checksum_truncation_and_garbage_classes() -> None:
    good = CODEC.encode("HDT", {"yaw": 0.5})
    with pytest.raises(NmeaError) as e:
        CODEC.decode(good[:-2] + "00")
    assert e.value.kind == "checksum"
    with pytest.raises(NmeaError) as e:
        CODEC.decode(good.split("*")[0])  # checksum missing
    assert e.value.kind == "checksum"
    with pytest.raises(NmeaError) as e:
        CODEC.decode(good[:8])  # truncated mid-sentence
    assert e.value.kind in ("checksum", "malformed")
    with pytest.raises(NmeaError) as e:
        CODEC.decode("\x00\xff garbage")
    assert e.value.kind == "malformed"
    with pytest.raises(NmeaError) as e:  # valid, but nothing the plant measures
        CODEC.decode("$GPGSA,A,3,04,05,,09,12,,,24,,,,,2.5,1.3,2.1*39")
    assert e.value.kind == "unsupported"
    with pytest.raises(NmeaError) as e:  # a DVL without bottom lock says so
        CODEC.decode(str(pynmea2.parse(CODEC.encode("PNORBT7", {"u": -32.768, "v": 0.0, "w": 0.0}))))
    assert e.value.kind == "invalid"


def _line(body: str) -> str:
    return f"${body}*{pynmea2.NMEASentence.checksum(body):02X}"


@pytest.mark.parametrize("field", ["1_0.0", "1_0", " 10", "10 ", "infinity", "nan", "0x10", "+-1", ".", "1e"])
def test_numbers_are_read_as_nmea_writes_them_or_dropped(field: str) -> None:
    """Python's float() takes "1_0" as 10: on the wire it is a malformed field, never a value."""
    with pytest.raises(NmeaError) as e:
        CODEC.decode(_line(f"SDDPT,{field},0.0,"))
    assert e.value.kind == "malformed" and "not a number" in str(e.value)
    with pytest.raises(NmeaError):
        CODEC.decode(_line(f"IIXDR,A,{field},D,ROLL,A,1.0,D,PITCH"))
    assert CODEC.decode(_line("SDDPT,10.,-0.5,")) == ("DPT", {"down": 9.5})
    assert CODEC.decode(_line("SDDPT,.5,,"))[1]["down"] == 0.5
    assert CODEC.decode(_line("SDDPT,1.5E1,,"))[1]["down"] == 15.0  # an exponent is the same value


def test_heading_must_be_true_and_vtg_course_may_be_empty() -> None:
    assert CODEC.decode(_line("HEHDT,90.0,T"))[1]["yaw"] == pytest.approx(math.pi / 2)
    with pytest.raises(NmeaError) as e:  # a magnetic heading is not the plant's yaw
        CODEC.decode(_line("HEHDT,90.0,M"))
    assert e.value.kind == "malformed" and "expected T" in str(e.value)
    # a receiver standing still (DP) sends no course: the speed is still read
    assert CODEC.decode(_line("GPVTG,,T,,M,1.0,N,1.852,K,D")) == ("VTG", {"sog": pytest.approx(1852 / 3600)})
    _, v = CODEC.decode(_line("GPVTG,45.0,T,,M,1.0,N,1.852,K,D"))
    assert v["course"] == pytest.approx(math.pi / 4)


def test_default_sentences_cover_both_vessels() -> None:
    m2 = {s.name: default_sentences(s) for s in load_vessel("minerva2").sensors}
    assert m2 == {
        "usbl": ["GGA"],
        "depth": ["DPT"],
        "ahrs": ["XDR_ATTITUDE", "HDT"],
        "dvl": ["PNORBT7"],
        "gyro": ["XDR_RATES"],
    }
    amv = {s.name: default_sentences(s) for s in load_vessel("amv_osf").sensors}
    assert amv == {"gnss": ["GGA"], "compass": ["HDT"], "gyro": ["ROT"], "speed": ["VBW"]}


# -- CAN ---------------------------------------------------------------------------------------

SEAFMU = SeafmuCodec(N_MAX, HERE / "seafmu_thrusters.dbc")
N2K = Nmea2000Codec(N_MAX, HERE / "nmea2000_thrusters.dbc")


@settings(max_examples=200, deadline=None)
@given(st.integers(0, 6), st.floats(-1.0, 1.0), st.booleans(), st.integers(0, 10_000), st.integers(0, 15))
def test_can_round_trip(i: int, frac: float, enable: bool, counter: int, faults: int) -> None:
    n = frac * N_MAX[i]
    cmd = SEAFMU.decode(SEAFMU.command(i, n, enable, counter))
    assert cmd == Command(i, pytest.approx(n, abs=0.005), enable, counter % 16)  # the alive counter
    (st_msg,) = SEAFMU.status(i, n, enable, faults, counter)
    fb = SEAFMU.decode(st_msg)
    assert isinstance(fb, Feedback) and fb.index == i and fb.enabled == enable and fb.faults == faults
    assert fb.speed == pytest.approx(n, abs=0.005)
    # NMEA 2000: speed in whole percent of n_max, direction from the sign
    step = N_MAX[i] / 100.0
    c2 = N2K.decode(N2K.command(i, n, enable, counter))
    assert isinstance(c2, Command) and c2.index == i and c2.enable == enable and c2.counter == counter % 252
    assert c2.speed == pytest.approx(n if enable else 0.0, abs=step / 2 + 1e-9)
    state, motor = N2K.status(i, n, enable, faults, counter)
    f_state, f_motor = N2K.decode(state), N2K.decode(motor)
    assert isinstance(f_state, Feedback) and f_state.speed == pytest.approx(
        n if enable else 0.0, abs=step / 2 + 1e-9
    )
    assert isinstance(f_motor, Feedback) and f_motor.faults == faults & ~4  # 128008 has no timeout bit


@settings(max_examples=500, deadline=None)
@given(st.integers(0, 0x1FFFFFFF), st.booleans(), st.binary(max_size=8), st.booleans())
def test_random_frames_never_crash_the_can_decoders(arb: int, ext: bool, data: bytes, remote: bool) -> None:
    msg = can.Message(
        arbitration_id=arb if ext else arb & 0x7FF,
        is_extended_id=ext,
        data=data,
        is_remote_frame=remote,
        dlc=len(data),
    )
    for codec in (SEAFMU, N2K):
        try:
            out = codec.decode(msg)
        except CanFrameError as exc:
            assert exc.kind in ("unknown_id", "wrong_dlc", "decode", "unexpected", "implausible_feedback")
        else:
            assert isinstance(out, Command | Feedback) and 0 <= out.index < 7


def test_can_error_classes() -> None:
    good = SEAFMU.command(0, 1.0, True, 0)
    with pytest.raises(CanFrameError) as e:
        SEAFMU.decode(can.Message(arbitration_id=0x7FF, data=good.data, is_extended_id=False))
    assert e.value.kind == "unknown_id"
    with pytest.raises(CanFrameError) as e:
        SEAFMU.decode(
            can.Message(arbitration_id=good.arbitration_id, data=good.data[:3], is_extended_id=False)
        )
    assert e.value.kind == "wrong_dlc"
    with pytest.raises(CanFrameError) as e:  # thruster 8 exists in the DBC, not on this vessel
        SEAFMU.decode(can.Message(arbitration_id=0x188, data=bytes(4), is_extended_id=False))
    assert e.value.kind == "unknown_id"
