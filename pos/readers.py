"""The input files of the GNSS/INS modes recognised by content, in one place: two registries of readers.

- IMU (`IMU_READERS`): a ROS 1/2 bag (sensor_msgs/Imu), a PX4 .ulg, dgcal's IMU CSV (a header naming gps_week and
  gps_sow), KF-GINS text (sow, angle and velocity increments); any other layout through a description
  (`dgcal.pos.ins.imu_formats`: a preset or TOML, with overrides and an RTKLIB time-tag file).
- Antenna positions (`FIX_READERS`): a ROS bag (sensor_msgs/NavSatFix), RTKLIB .pos, NMEA GGA, dgcal gnss.csv.
Each entry is (name, recognises(path) -> bool, read); the first entry that recognises a file reads it, and a
named format skips the recognition.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from dgcal.fields.errors import InputError
from dgcal.pos.gnss.solution_files import GnssSolution, read_gnss_solution, select_quality, sniff_gnss_format
from dgcal.pos.ins.imu_data import ImuData, read_imu_csv, read_kf_gins
from dgcal.pos.ins.imu_formats import imu_format, read_imu
from dgcal.pos.ins.ulog import is_ulog, read_ulog_imu
from dgcal.pos.ros_bags import is_ros_bag, read_rosbag_imu, read_rosbag_navsatfix


@dataclass
class ImuInput:
    """An IMU file and how to read it: a description (preset name or TOML; None: recognised by content), overrides
    `KEY=VALUE` of it, an RTKLIB time-tag file, and seconds added to every sample time (a logger's delay)."""

    path: Path | None = None
    format: str | None = None
    overrides: tuple[str, ...] = ()
    tag: Path | None = None
    time_offset_s: float = 0.0


@dataclass
class FixInput:
    """GNSS antenna positions of a receiver's own solution (lc, ukf): a dgcal gnss.csv, RTKLIB .pos, NMEA GGA or
    ROS bag (`format` None: recognised by content), the fix qualities to use ("fixed,float"; None: all), the UTC
    date of an NMEA log without RMC, and outages (start, length, period s) whose fixes are withheld to check."""

    path: Path | None = None
    format: str | None = None
    quality: str | None = None
    nmea_date: str | None = None
    outages: tuple[float, float, float] | None = None


def is_dgcal_imu_csv(path: Path) -> bool:
    """A text file whose first data line (after # or % comments) names gps_week and gps_sow."""
    try:
        with open(path, encoding="utf-8-sig", errors="replace") as fh:
            for line in fh:
                s = line.strip()
                if s and not s.startswith(("#", "%")):
                    low = s.lower()
                    return "gps_week" in low and "gps_sow" in low
    except OSError as exc:
        raise InputError(f"cannot read: {exc}", path) from None
    return False


def _text_file(path: Path) -> bool:
    return path.is_file()


IMU_READERS = (
    ("rosbag", is_ros_bag, lambda path, week: read_rosbag_imu(path)),
    ("px4-ulog", lambda p: p.is_file() and is_ulog(p), lambda path, week: read_ulog_imu(path)),
    ("dgcal", lambda p: p.is_file() and is_dgcal_imu_csv(p), lambda path, week: read_imu_csv(path)),
    ("kf-gins", _text_file, lambda path, week: read_kf_gins(path, gps_week=week)),
)


def recognise_imu(path: str | Path) -> str:
    """The name of the `IMU_READERS` entry that reads `path`; InputError when it does not exist."""
    path = Path(path)
    if not path.exists():
        raise InputError("file not found", path)
    for name, recognises, _read in IMU_READERS:
        if recognises(path):
            return name
    raise InputError("not an IMU file (a ROS bag, PX4 .ulg, dgcal CSV or KF-GINS text)", path)


def read_imu_input(inp: ImuInput, gps_week: int | None = None) -> ImuData:
    """The IMU samples of `inp` (GPS s, rad and m/s increments or rates in body FRD), with `time_offset_s` added:
    by its description when it has one (or overrides or a tag file), else by the reader that recognises it.
    `gps_week`: the week of files whose times are seconds of week."""
    path = Path(inp.path)
    if inp.format is None and not inp.overrides and inp.tag is None:
        name = recognise_imu(path)
        imu = dict((n, r) for n, _s, r in IMU_READERS)[name](path, gps_week)
        if inp.time_offset_s:
            imu.t = imu.t + float(inp.time_offset_s)
        return imu
    if not path.is_file():
        raise InputError("file not found", path)
    fmt = imu_format(inp.format if inp.format is not None else "kf-gins", inp.overrides,
                     time_offset_s=inp.time_offset_s)
    return read_imu(path, fmt, tag=inp.tag, gps_week=gps_week)


FIX_READERS = (
    ("rosbag", is_ros_bag, lambda inp: read_rosbag_navsatfix(inp.path)),
    ("rtklib-pos", lambda p: p.is_file() and sniff_gnss_format(p) == "rtklib-pos",
     lambda inp: read_gnss_solution(inp.path, "rtklib-pos")),
    ("nmea", lambda p: p.is_file() and sniff_gnss_format(p) == "nmea",
     lambda inp: read_gnss_solution(inp.path, "nmea", inp.nmea_date)),
    ("dgcal-csv", lambda p: p.is_file() and sniff_gnss_format(p) == "dgcal-csv",
     lambda inp: read_gnss_solution(inp.path, "dgcal-csv")),
)


def read_fix_input(inp: FixInput) -> GnssSolution:
    """Antenna positions (ECEF m, NED covariances, fix quality) of `inp` in the qualities it asks for: read by its
    named format or by the reader that recognises it."""
    path = Path(inp.path)
    readers = {n: r for n, _s, r in FIX_READERS}
    if inp.format is not None:
        if inp.format not in readers:
            raise InputError(f"unknown format {inp.format!r} (one of {', '.join(readers)})", path, field="format")
        name = inp.format
    elif not path.exists():
        raise InputError("file not found", path)
    else:   # the text formats' recognisers raise InputError naming the file when nothing recognises it
        name = next(n for n, recognises, _r in FIX_READERS if recognises(path))
    return select_quality(readers[name](inp), inp.quality)
