"""Hardware profiles: which serial port, which CAN adapter and DBC, which NMEA sentence carries which
sensor, and the safety limits — one YAML file per vessel installation (``hardware/profiles/``).

The same profile drives the link (seafmu side) and the emulator (vessel side), so the two agree on
the sentences without a second source of truth. Every mistake is one line naming file and field.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

HERE = Path(__file__).resolve().parent
PROFILE_DIR = HERE / "profiles"


class ProfileError(ValueError):
    """A hardware profile that cannot be used; one line naming the file and field."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class SerialConfig(_Strict):
    url: str = Field(description="pyserial URL: /dev/ttyUSB0, /dev/pts/5, loop://, socket://127.0.0.1:PORT")
    baudrate: int = Field(115200, gt=0)
    options: dict[str, Any] = Field(
        default_factory=dict, description="more keyword arguments of serial_for_url"
    )


class CanConfig(_Strict):
    interface: str = Field(description="python-can interface: slcan, socketcan, virtual, pcan, kvaser, ...")
    channel: str = Field(description="its channel: /dev/ttyACM0 (slcan), can0 (socketcan), a name (virtual)")
    bitrate: int | None = Field(500000, description="bus bitrate; null for interfaces that take none")
    options: dict[str, Any] = Field(default_factory=dict, description="more keyword arguments of can.Bus")
    mapping: Literal["seafmu", "nmea2000"] = Field(
        "seafmu",
        description="seafmu: one command/status message per thruster (seafmu_thrusters.dbc); "
        "nmea2000: PGN 128006/128008 (nmea2000_thrusters.dbc)",
    )
    dbc: str | None = Field(None, description="DBC file (default: the mapping's file in hardware/)")
    source_address: int = Field(0x10, ge=0, le=253, description="NMEA 2000 source address of seafmu")
    thruster_address: int = Field(
        0x20, ge=0, le=253, description="NMEA 2000: source address of thruster 1 (i-th: + i - 1)"
    )
    status_counter: bool = Field(
        True,
        description="the drives advance their status alive counter (NMEA 2000: SID) with every frame, "
        "so a status repeating the previous one's is a hung drive's repeat, not fresh; false for "
        "drives that do not count: then only their silence is checked",
    )


class Origin(_Strict):
    lat: float = Field(ge=-89.0, le=89.0, description="latitude of the NED origin, deg")
    lon: float = Field(ge=-180.0, le=180.0, description="longitude of the NED origin, deg")


class WatchdogConfig(_Strict):
    timeout: float = Field(
        0.5,
        gt=0,
        description="s: thrusters are zero at the latest this long after "
        "the last fresh datum of a watched source",
    )
    sources: list[str] | None = Field(
        None,
        description="watched sensors (vessel file names) and/or "
        "'thrusters' (CAN status frames); default: every sensor whose "
        "period is shorter than half the timeout, and the thrusters",
    )
    resume_ramp: float = Field(
        1.0, ge=0, description="s: commands ramp from 0 back to the allocator's after the alarm clears"
    )


class RecordConfig(_Strict):
    dir: str | None = Field(None, description="folder for the recording (none: do not record)")
    can_format: Literal["asc", "blf", "log", "csv", "trc"] = Field(
        "asc", description="python-can log format of the raw CAN traffic"
    )


class HardwareProfile(_Strict):
    name: str
    description: str = ""
    vessel: str = Field(description="vessel file name (components/vessels) or path")
    serial: SerialConfig
    can: CanConfig
    origin: Origin = Field(
        default_factory=lambda: Origin(lat=63.44, lon=10.40),
        description="NED origin for GGA/RMC positions (default: Trondheimsfjord)",
    )
    sensors: dict[str, list[str]] | None = Field(
        None, description="sensor name -> NMEA sentences that make one sample (default: by channels)"
    )
    talkers: dict[str, str] = Field(default_factory=dict, description="sentence -> talker id to send with")
    watchdog: WatchdogConfig = Field(default_factory=WatchdogConfig)
    startup_timeout: float = Field(5.0, gt=0, description="s: wait for a first sample of every sensor")
    reconnect_interval: float = Field(1.0, gt=0, description="s between attempts to reopen a lost port")
    command_timeout: float = Field(
        0.5,
        gt=0,
        description="s: the drive (emulator; a real drive must be set to the same) stops and disables "
        "a thruster that received no fresh command (alive counter advancing) for this long; "
        "seafmu DBC: latched until enable 0 then 1; nmea2000: at most 0.253 (128006 Command Timeout)",
    )
    command_counter_max_delta: int = Field(
        3,
        ge=1,
        le=15,
        description="largest alive-counter advance a drive takes as fresh (1 + frames that may be lost "
        "in a row); a repeated counter is always stale, a larger jump re-synchronises",
    )
    record: RecordConfig = Field(default_factory=RecordConfig)
    realtime_priority: int | None = Field(
        None,
        ge=1,
        le=99,
        description="SCHED_FIFO priority of the loop (needs root or CAP_SYS_NICE; none: normal scheduling)",
    )
    source: str = ""  # file it was read from (filled by load_profile)

    @field_validator("sensors")
    @classmethod
    def _non_empty(cls, v: dict[str, list[str]] | None) -> dict[str, list[str]] | None:
        for name, sentences in (v or {}).items():
            if not sentences:
                raise ValueError(f"sensor '{name}' needs at least one sentence")
        return v

    def dbc_path(self) -> Path:
        if self.can.dbc:
            p = Path(self.can.dbc)
            if not p.is_absolute():
                base = Path(self.source).parent if self.source else HERE
                p = base / p if (base / p).is_file() else HERE / p
            return p
        return HERE / ("seafmu_thrusters.dbc" if self.can.mapping == "seafmu" else "nmea2000_thrusters.dbc")

    def with_overrides(self, **overrides: Any) -> HardwareProfile:
        """A copy with dotted fields replaced: ``with_overrides(**{"serial.url": "loop://"})``."""
        data = self.model_dump()
        for key, value in overrides.items():
            node = data
            *head, last = key.split(".")
            for part in head:
                node = node[part]
            node[last] = value
        return _validate(data, Path(self.source or "<profile>"))


def bundled_profiles() -> list[str]:
    return sorted(p.stem for p in PROFILE_DIR.glob("*.yaml"))


def profile_path(name_or_path: str | Path) -> Path:
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml"):
        return p
    return PROFILE_DIR / f"{name_or_path}.yaml"


def load_profile(name_or_path: str | Path | HardwareProfile) -> HardwareProfile:
    """A bundled profile name (``emulator_pty``) or a path to a profile YAML file."""
    if isinstance(name_or_path, HardwareProfile):
        return name_or_path
    path = profile_path(name_or_path)
    if not path.is_file():
        from ..components.names import did_you_mean

        bundled = bundled_profiles()
        raise ProfileError(f"hardware profile '{name_or_path}': no such file {path}"
                           f"{did_you_mean(str(name_or_path), bundled)} (bundled: {', '.join(bundled)})")
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise ProfileError(f"{path}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(doc, dict):
        raise ProfileError(f"{path}: expected a mapping of profile fields at the top level")
    doc["source"] = str(path)
    return _validate(doc, path)


def _validate(doc: dict[str, Any], path: Path) -> HardwareProfile:
    try:
        return HardwareProfile.model_validate(doc)
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = ".".join(str(p) for p in err["loc"]) or "(top level)"
        msg = {"extra_forbidden": "unknown field", "missing": "required field is missing"}.get(
            err["type"], err["msg"]
        )
        raise ProfileError(f"{path}: {loc}: {msg}") from None
