"""Fault injection on the hardware link's decoders: frames a sensor or adapter can put on the wire that
carry a number but must not be read as a measurement (review 17). Pure API, no ports."""

from __future__ import annotations

import can
import numpy as np
import pynmea2
import pytest

from seafmu.hardware.canbus import CanFrameError, Nmea2000Codec, SeafmuCodec
from seafmu.hardware.nmea import NmeaCodec, NmeaError
from seafmu.hardware.profile import HERE

CODEC = NmeaCodec(63.44, 10.40)
SEAFMU = SeafmuCodec(np.full(7, 20.0), HERE / "seafmu_thrusters.dbc")
N2K = Nmea2000Codec(np.full(7, 20.0), HERE / "nmea2000_thrusters.dbc")


def _line(body: str) -> str:
    return f"${body}*{pynmea2.NMEASentence.checksum(body):02X}"


def _drop(line: str) -> NmeaError:
    with pytest.raises(NmeaError) as e:
        CODEC.decode(line)
    return e.value


def _accepted(line: str) -> bool:
    try:
        CODEC.decode(line)
    except NmeaError:
        return False
    return True


def _gga(quality: str) -> str:
    return _line(f"GPGGA,120000.00,6326.4000,N,01024.0000,E,{quality},08,1.0,0.0,M,0.0,M,,")


# -- NMEA 0183 ---------------------------------------------------------------------------------


def test_gga_only_measured_qualities_are_a_fix() -> None:
    """NMEA 0183: 1 GPS, 2 DGPS, 3 PPS, 4 RTK fixed, 5 RTK float (and 9 SBAS, from some receivers);
    0 no fix, 6 dead reckoning, 7 manual input, 8 simulation."""
    read = {q for q in "0123456789" if _accepted(_gga(q))}
    assert read == set("123459")
    _, v = CODEC.decode(_gga("4"))
    assert v == {"north": pytest.approx(0.0, abs=1e-6), "east": pytest.approx(0.0, abs=1e-6)}


@pytest.mark.parametrize("quality", ["6", "7", "8"])
def test_gga_dead_reckoned_manual_or_simulated_position_is_not_a_fix(quality: str) -> None:
    err = _drop(_gga(quality))
    assert err.kind == "invalid" and f"quality {quality}" in str(err)
    assert "not a measured position" in str(err)


@pytest.mark.parametrize("quality", ["x", "10", "1.0", "-1", " 1"])
def test_gga_fix_quality_outside_the_table_is_malformed(quality: str) -> None:
    err = _drop(_gga(quality))
    assert err.kind == "malformed" and "fix quality" in str(err)


@pytest.mark.parametrize("mode", ["E", "M", "S", "N"])
def test_rmc_and_vtg_modes_without_a_measurement_are_invalid(mode: str) -> None:
    rmc = f"GPRMC,120000.00,A,6326.4000,N,01024.0000,E,1.0,45.0,010125,,,{mode}"
    err = _drop(_line(rmc))
    assert err.kind == "invalid" and f"mode {mode}" in str(err)
    err = _drop(_line(f"GPVTG,45.0,T,,M,1.0,N,1.852,K,{mode}"))
    assert err.kind == "invalid" and f"mode {mode}" in str(err)
    assert CODEC.decode(_line(rmc[:-1] + "D"))[0] == "RMC"  # the same sentence, differential: read
    assert CODEC.decode(_line(rmc[:-2]))[0] == "RMC"  # NMEA 0183 before 2.3: no mode field


@pytest.mark.parametrize("body", ["HEHDT,45.0", "HEHDT,45.0,"])
def test_hdt_without_its_true_reference_is_malformed(body: str) -> None:
    err = _drop(_line(body))
    assert err.kind == "malformed" and "expected T" in str(err)
    assert CODEC.decode(_line("HEHDT,45.0,T"))[0] == "HDT"


@pytest.mark.parametrize(
    "body",
    [
        "IIXDR,A,1,D,ROLL,A,2,D,ROLL",
        "IIXDR,A,1,D,ROLL,A,0,D,PITCH,A,2,D,roll",
        "IIXDR,A,0,D,YAWRATE,A,0,D,PITCHRATE,A,1,D,YAWRATE",
    ],
)
def test_xdr_with_one_transducer_twice_is_ambiguous(body: str) -> None:
    err = _drop(_line(body))
    assert err.kind == "malformed" and "twice" in str(err)


@pytest.mark.parametrize(
    "line",
    [
        _line("SDDPT,5.0,0.0,$HEHDT,45,T"),  # two sentences run together, checksum over both
        _line("SDDPT,5.0,0.0,!AIVDM"),
        _line("SDDPT,5.0,0.0,\x01"),  # a control character in a field nothing reads
        _line("SDDPT,5.0,0.0,\x7f"),
    ],
)
def test_reserved_or_unprintable_characters_are_malformed(line: str) -> None:
    assert _drop(line).kind == "malformed"


def test_a_query_is_unsupported_not_a_truncated_sentence() -> None:
    err = _drop(_line("CCGPQ,GGA"))
    assert err.kind == "unsupported" and "query" in str(err)


# -- CAN ---------------------------------------------------------------------------------------


def _slcan(*lines: bytes) -> list[can.Message]:
    """What python-can's SLCAN driver makes of adapter lines (over a pyserial loopback)."""
    bus = can.Bus(interface="slcan", channel="loop://", bitrate=500000)
    try:
        while bus.recv(0.0) is not None:  # the driver's own setup commands, echoed
            pass
        out = []
        for raw in lines:
            bus.serialPortOrig.write(raw)
            msg = bus.recv(1.0)
            assert msg is not None
            out.append(msg)
        return out
    finally:
        bus.shutdown()


def test_slcan_frame_with_fewer_data_bytes_than_its_dlc_says_so() -> None:
    """``t1814``: python-can keeps DLC 4 with no data; "DLC 4, expected 4" explained nothing."""
    short, long9 = _slcan(b"t1814\r", b"t1819" + b"00" * 12 + b"\r")
    with pytest.raises(CanFrameError) as e:
        SEAFMU.decode(short)
    assert e.value.kind == "wrong_dlc" and "0 data bytes where its DLC says 4" in str(e.value)
    with pytest.raises(CanFrameError) as e:  # DLC digit 9: python-can maps it to 12, reads 9 bytes
        SEAFMU.decode(long9)
    assert e.value.kind == "wrong_dlc" and "9 data bytes where its DLC says 12" in str(e.value)


def test_can_fd_or_error_frame_with_a_thruster_id_is_dropped() -> None:
    (fd,) = _slcan(b"d181464000101\r")  # CAN FD, id 0x181, a plausible THR_STATUS_1 payload
    assert fd.is_fd
    with pytest.raises(CanFrameError) as e:
        SEAFMU.decode(fd)
    assert e.value.kind == "unexpected" and "CAN FD" in str(e.value)
    good = SEAFMU.status(0, 1.0, True, 0, 1)[0]
    err = can.Message(arbitration_id=0x181, is_extended_id=False, is_error_frame=True, data=good.data)
    with pytest.raises(CanFrameError) as e:
        SEAFMU.decode(err)
    assert e.value.kind == "unexpected" and "error frame" in str(e.value)
    state = N2K.status(0, 5.0, True, 0, 1)[0]
    fd2k = can.Message(arbitration_id=state.arbitration_id, data=state.data, is_extended_id=True, is_fd=True)
    with pytest.raises(CanFrameError) as e:
        N2K.decode(fd2k)
    assert e.value.kind == "unexpected"


def test_gga_sbas_fix_quality_9_is_a_measurement() -> None:
    """Quality 9 is outside NMEA 0183's 0-8 table but some receivers send it for an SBAS (WAAS,
    EGNOS) differential fix: a real measured position, read as one."""
    assert CODEC.decode(_gga("9"))[0] == "GGA"
