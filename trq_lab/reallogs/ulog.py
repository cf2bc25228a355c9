"""A PX4 ULog's sensors and its own EKF2's outputs, read with pyulog into plain arrays.

    log = read_ulog(path)                   # everything the log has, per topic
    log.require("sensor_combined", for_="trq-ulog-replay")   # LogError naming topic and file

Layouts read (PX4 has moved fields between topics over the years):

    IMU          sensor_combined: gyro_rad (the mean rate over gyro_integral_dt ending at
                 `timestamp`), accelerometer_m_s2 (at timestamp + accelerometer_timestamp_relative);
                 integral dt in seconds (float, before v1.10) or microseconds (integer)
    magnetometer vehicle_magnetometer.magnetometer_ga, or (old) sensor_combined.magnetometer_ga
                 at timestamp + magnetometer_timestamp_relative (each reading repeated until the
                 next: kept once)
    barometer    vehicle_air_data.baro_alt_meter, or (old) sensor_combined.baro_alt_meter
    GNSS         sensor_gps, else vehicle_gps_position: latitude_deg / longitude_deg /
                 altitude_msl_m, or (old) lat / lon (1e-7 deg) and alt (mm); vel_n/e/d_m_s;
                 eph, epv
    vision       vehicle_visual_odometry: x, y, z and q, or (new) position[3] and q[4], in
                 the NED pose frame (a sample in another pose_frame is left out)
    EKF2         vehicle_attitude.q; vehicle_local_position x, y, z, vx, vy, vz (ref_lat,
                 ref_lon, ref_alt its origin); estimator_innovations (new) and estimator_status's
                 test ratios (every layout)
    rotors       esc_status.esc[i].esc_rpm, actuator_outputs.output[i], actuator_motors.control[i]

Times are the log's microseconds (integers). Every sample's time is its time of validity where the
log says it (`timestamp_sample`), else its publication time. Nothing here fuses, fits or plots.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["LogError", "Series", "UlogData", "read_ulog", "gnss_to_ned"]

_INVALID_RELATIVE = 2_147_483_647       # PX4's RELATIVE_TIMESTAMP_INVALID (INT32_MAX)
_EARTH_RADIUS_M = 6_371_000.0           # the mean earth radius (PX4's CONSTANTS_RADIUS_OF_EARTH)


class LogError(ValueError):
    """A log a command cannot use: names the file and the topic (or what else is missing)."""


@dataclass(frozen=True)
class Series:
    """One signal: times (n,) in the log's microseconds and values (n, k)."""
    t_us: np.ndarray
    values: np.ndarray

    def __len__(self) -> int:
        return len(self.t_us)


@dataclass(frozen=True)
class UlogData:
    file: str
    topics: frozenset[str]
    params: dict[str, float]
    gyro_rad_s: Series | None = None            # (n, 3) body FRD
    accel_m_s2: Series | None = None            # (n, 3) body FRD specific force
    mag_gauss: Series | None = None             # (n, 3) body FRD
    baro_alt_m: Series | None = None            # (n, 1) pressure altitude, up
    gnss: Series | None = None      # (n, 8): lat deg, lon deg, alt m, vn, ve, vd m/s, eph, epv m
    vision: Series | None = None                # (n, 7): x, y, z NED m, qw, qx, qy, qz
    ekf2_quat: Series | None = None             # (n, 4) wxyz body FRD -> NED
    ekf2_pos_vel: Series | None = None          # (n, 6) NED m, m/s
    ekf2_origin: tuple[float, float, float] | None = None   # ref lat deg, lon deg, alt m
    ekf2_test_ratios: Series | None = None      # (n, 4) vel, pos (horizontal), hgt, mag
    ekf2_innovations: dict[str, Series] = field(default_factory=dict)
    rotor_rpm: Series | None = None             # (n, m) esc_status
    motor_fraction: Series | None = None        # (n, m) 0..1: actuator_motors or actuator_outputs

    def require(self, *names: str, for_: str) -> None:
        """LogError unless every named signal is there."""
        what = {"gyro_rad_s": "sensor_combined", "accel_m_s2": "sensor_combined",
                "mag_gauss": "vehicle_magnetometer (or sensor_combined.magnetometer_ga)",
                "baro_alt_m": "vehicle_air_data (or sensor_combined.baro_alt_meter)",
                "gnss": "sensor_gps (or vehicle_gps_position) with a 3D fix",
                "vision": "vehicle_visual_odometry", "ekf2_quat": "vehicle_attitude",
                "ekf2_pos_vel": "vehicle_local_position", "ekf2_test_ratios": "estimator_status",
                "rotor_rpm": "esc_status",
                "motor_fraction": "actuator_motors (or actuator_outputs)"}
        for n in names:
            if getattr(self, n) is None or len(getattr(self, n)) == 0:
                raise LogError(f"{self.file}: {for_} needs topic {what.get(n, n)}, which the "
                               f"log does not carry (its topics: {', '.join(sorted(self.topics))})")


def _col(d: dict, *names: str) -> np.ndarray | None:
    for n in names:
        if n in d:
            return np.asarray(d[n])
    return None


def _vec(d: dict, stem: str, n: int) -> np.ndarray | None:
    cols = [d.get(f"{stem}[{i}]") for i in range(n)]
    if any(c is None for c in cols):
        return None
    return np.column_stack(cols).astype(float)


def _times(d: dict) -> np.ndarray:
    t = d.get("timestamp_sample")
    if t is None or not np.any(t):
        t = d["timestamp"]
    return np.asarray(t, dtype=np.int64)


def _relative(d: dict, key: str) -> np.ndarray | None:
    """(times, row indices) of the distinct readings an old sensor_combined repeats."""
    rel = d.get(key)
    if rel is None:
        return None
    ok = rel.astype(np.int64) != _INVALID_RELATIVE
    t = d["timestamp"].astype(np.int64) + rel.astype(np.int64)
    idx = np.flatnonzero(ok)
    if len(idx) == 0:
        return None
    t_ok = t[idx]
    keep = np.concatenate(([True], np.diff(t_ok) > 0))
    return idx[keep]


def read_ulog(path: str | Path) -> UlogData:
    """The log's sensors and EKF2 outputs (LogError when the file is not a ULog)."""
    from pyulog import ULog     # a well-kept parser of PX4's format (pyproject: dependencies)

    path = Path(path)
    if not path.is_file():
        raise LogError(f"{path}: no such file")
    try:
        u = ULog(str(path))
    except Exception as exc:    # pyulog raises bare Exceptions on a bad header
        raise LogError(f"{path}: not a readable ULog ({exc})") from exc
    by_name: dict[str, dict] = {}
    for ds in u.data_list:
        if ds.multi_id == 0 and len(ds.data.get("timestamp", ())):
            by_name[ds.name] = ds.data
    f: dict = dict(file=str(path), topics=frozenset(by_name),
                   params={k: float(v) for k, v in u.initial_parameters.items()})

    sc = by_name.get("sensor_combined")
    if sc is not None:
        t = sc["timestamp"].astype(np.int64)
        f["gyro_rad_s"] = Series(t, _vec(sc, "gyro_rad", 3))
        rel = sc.get("accelerometer_timestamp_relative")
        ta = t + (rel.astype(np.int64) if rel is not None else 0)
        f["accel_m_s2"] = Series(ta, _vec(sc, "accelerometer_m_s2", 3))
    mag = by_name.get("vehicle_magnetometer")
    if mag is not None:
        f["mag_gauss"] = Series(_times(mag), _vec(mag, "magnetometer_ga", 3))
    elif sc is not None and "magnetometer_ga[0]" in sc:
        idx = _relative(sc, "magnetometer_timestamp_relative")
        if idx is not None:
            t = sc["timestamp"].astype(np.int64) + sc["magnetometer_timestamp_relative"]
            f["mag_gauss"] = Series(t[idx], _vec(sc, "magnetometer_ga", 3)[idx])
    air = by_name.get("vehicle_air_data")
    if air is not None:
        f["baro_alt_m"] = Series(_times(air), air["baro_alt_meter"].astype(float)[:, None])
    elif sc is not None and "baro_alt_meter" in sc:
        idx = _relative(sc, "baro_timestamp_relative")
        if idx is not None:
            t = sc["timestamp"].astype(np.int64) + sc["baro_timestamp_relative"]
            f["baro_alt_m"] = Series(t[idx], sc["baro_alt_meter"].astype(float)[idx, None])
    # the receiver's topic, or the selected one (PX4 logs each at its own rate: the denser)
    gps = max((by_name[k] for k in ("sensor_gps", "vehicle_gps_position") if k in by_name),
              key=lambda d: len(d["timestamp"]), default=None)
    if gps is not None:
        fix = _col(gps, "fix_type")
        ok = fix >= 3 if fix is not None else np.ones(len(gps["timestamp"]), bool)
        lat = _col(gps, "latitude_deg")
        if lat is None:
            lat, lon, alt = gps["lat"] * 1e-7, gps["lon"] * 1e-7, gps["alt"] * 1e-3
        else:
            lon, alt = gps["longitude_deg"], _col(gps, "altitude_msl_m", "altitude_ellipsoid_m")
        cols = np.column_stack((lat, lon, alt, gps["vel_n_m_s"], gps["vel_e_m_s"],
                                gps["vel_d_m_s"], gps["eph"], gps["epv"])).astype(float)
        if ok.any():
            f["gnss"] = Series(_times(gps)[ok], cols[ok])
    vo = by_name.get("vehicle_visual_odometry")
    if vo is not None:
        pos = _vec(vo, "position", 3)
        if pos is None and "x" in vo:
            pos = np.column_stack((vo["x"], vo["y"], vo["z"])).astype(float)
        q = _vec(vo, "q", 4)
        if pos is not None and q is not None:
            good = np.isfinite(pos).all(axis=1) & np.isfinite(q).all(axis=1)
            if "pose_frame" in vo:      # vehicle_odometry's POSE_FRAME_NED (1) only: an FRD
                good &= vo["pose_frame"] == 1       # frame's heading is not the filter's
            f["vision"] = Series(_times(vo)[good], np.hstack((pos, q))[good])
    att = by_name.get("vehicle_attitude")
    if att is not None:
        f["ekf2_quat"] = Series(att["timestamp"].astype(np.int64), _vec(att, "q", 4))
    lp = by_name.get("vehicle_local_position")
    if lp is not None:
        f["ekf2_pos_vel"] = Series(lp["timestamp"].astype(np.int64), np.column_stack(
            [lp[k] for k in ("x", "y", "z", "vx", "vy", "vz")]).astype(float))
        if "ref_lat" in lp and lp["ref_lat"][-1] != 0:
            f["ekf2_origin"] = (float(lp["ref_lat"][-1]), float(lp["ref_lon"][-1]),
                                float(lp["ref_alt"][-1]))
    st = by_name.get("estimator_status")
    if st is not None and "vel_test_ratio" in st:
        f["ekf2_test_ratios"] = Series(st["timestamp"].astype(np.int64), np.column_stack(
            [st[k] for k in ("vel_test_ratio", "pos_test_ratio", "hgt_test_ratio",
                             "mag_test_ratio")]).astype(float))
    inn = by_name.get("estimator_innovations")
    if inn is not None:
        t = _times(inn)
        groups = {"gnss_pos": ("gps_hpos[0]", "gps_hpos[1]", "gps_vpos"),
                  "gnss_vel": ("gps_hvel[0]", "gps_hvel[1]", "gps_vvel"),
                  "baro": ("baro_vpos",), "mag": ("mag_field[0]", "mag_field[1]", "mag_field[2]"),
                  "vision_pos": ("ev_hpos[0]", "ev_hpos[1]", "ev_vpos")}
        f["ekf2_innovations"] = {k: Series(t, np.column_stack([inn[c] for c in cols]).astype(float))
                                 for k, cols in groups.items() if all(c in inn for c in cols)}
    esc = by_name.get("esc_status")
    if esc is not None:
        n = int(np.max(esc.get("esc_count", [0]))) or 0
        rpm = [esc[f"esc[{i}].esc_rpm"] for i in range(n) if f"esc[{i}].esc_rpm" in esc]
        if rpm:
            f["rotor_rpm"] = Series(esc["timestamp"].astype(np.int64),
                                    np.abs(np.column_stack(rpm).astype(float)))
    mot = by_name.get("actuator_motors")
    if mot is not None and "control[0]" in mot:
        cols = [mot[f"control[{i}]"] for i in range(12) if f"control[{i}]" in mot]
        m = np.column_stack(cols).astype(float)
        used = np.isfinite(m).all(axis=0)
        f["motor_fraction"] = Series(mot["timestamp"].astype(np.int64), np.clip(m[:, used], 0, 1))
    elif "actuator_outputs" in by_name:
        ao = by_name["actuator_outputs"]
        n = int(np.max(ao.get("noutputs", [4]))) or 4
        pwm = np.column_stack([ao[f"output[{i}]"] for i in range(min(n, 4))]).astype(float)
        # PWM 1000..2000 us: PX4's PWM_MAIN_MIN / PWM_MAIN_MAX defaults
        f["motor_fraction"] = Series(ao["timestamp"].astype(np.int64),
                                     np.clip((pwm - 1000.0) / 1000.0, 0.0, 1.0))
    return UlogData(**f)


def gnss_to_ned(lat_deg: np.ndarray, lon_deg: np.ndarray, alt_m: np.ndarray,
                origin: tuple[float, float, float]) -> np.ndarray:
    """(n, 3) NED metres of each fix from `origin` (lat deg, lon deg, alt m): the azimuthal
    equidistant projection PX4's map_projection uses, in its small-distance form."""
    lat0, lon0, alt0 = (math.radians(origin[0]), math.radians(origin[1]), origin[2])
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    north = (lat - lat0) * _EARTH_RADIUS_M
    east = (lon - lon0) * math.cos(lat0) * _EARTH_RADIUS_M
    return np.column_stack((north, east, -(np.asarray(alt_m, float) - alt0)))
