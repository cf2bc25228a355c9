"""`trq-ulog-replay LOG.ulg --out DIR`: a PX4 log's sensors through the vehicle's own filter
(sil_vehicle.estimator.Eskf), compared with the log's own EKF2.

    1. read the log (trq_lab.reallogs.ulog): IMU, magnetometer, barometer, GNSS or vision; EKF2's
       attitude, local position, innovations and test ratios; its EKF2_* parameters
    2. set the filter as EKF2 is set (trq_lab.reallogs.ekf2_params: the schema's Ekf2, PX4's
       defaults with the log's own EKF2_* values where it has them, through the vehicle's own
       EstimatorParams.ekf2; --px4-defaults ignores the log's)
    3. resample the IMU onto the filter's fixed 200 Hz grid (the exact integral of the log's
       samples over each 5 ms interval: a delta angle and delta velocity, as EKF2's own
       downsampler keeps them) and step the filter through the log with each aiding reading at
       its arrival (GNSS's time of validity its arrival less EKF2_GPS_DELAY, as EKF2 takes it;
       its noise EKF2's floor under the fix's reported eph / epv)
    4. compare after `--settle-s` from the filter's alignment: attitude as the angle between the
       two quaternions, tilt (the angle between the two gravity directions in body axes) and
       heading apart; velocity and position NED (the same origin: the log's EKF2 reference point;
       the height datum the log's at alignment); the innovations' RMS and the test ratios
    5. write DIR/report.md, DIR/metrics.json and DIR/*.png, all at once at the end (a log that
       lacks what the replay needs fails before anything is written: LogError naming topic and
       file)

Needs: sensor_combined, vehicle_attitude; uses what else the log has. Without GNSS or vision the
filter gets EKF2's fake position (the origin, EKF2_NOAID_NOISE), as EKF2 does when unaided.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sil_vehicle.estimator.eskf import Aid, Eskf
from sil_vehicle.frames import euler_to_quat, quat_to_dcm
from sil_vehicle.sensors.baro import BaroReading
from sil_vehicle.sensors.gnss import GnssReading
from sil_vehicle.sensors.imu import ImuReading
from sil_vehicle.sensors.mag import MagReading
from sil_vehicle.sensors.mocap import MocapReading
from trq_lab.reallogs.ekf2_params import Sources, ekf2_record, estimator_params, extra_values
from trq_lab.reallogs.output import write_all
from trq_lab.reallogs.ulog import LogError, Series, UlogData, gnss_to_ned, read_ulog

__all__ = ["IMU_RATE_HZ", "ReplayResult", "replay", "compare", "resample_imu", "main"]

IMU_RATE_HZ = 200               # the filter's IMU grid: two samples per 10 ms filter period
_FAKE_RATE_HZ = 5               # the fake position's rate when unaided: a choice
_ALIGN_S = 1.0                  # the span the magnetic field's direction is taken over: a choice


def resample_imu(s: Series, period_us: int) -> tuple[np.ndarray, np.ndarray]:
    """Grid times (multiples of period_us inside the log's span) and the mean of `s` over each
    grid interval (t - period, t]: the exact integral of the samples, each the mean over the
    interval ending at its time (PX4's integrated IMU), linear where two samples are apart."""
    t = s.t_us.astype(np.int64)
    keep = np.concatenate(([True], np.diff(t) > 0))
    t, v = t[keep], s.values[keep]
    knots = np.concatenate(([t[0] - (t[1] - t[0])], t)).astype(float)
    cum = np.vstack((np.zeros((1, v.shape[1])), np.cumsum(v * np.diff(knots)[:, None], axis=0)))
    g0 = -(-int(knots[0]) // period_us) * period_us
    grid = np.arange(g0, int(t[-1]) + 1, period_us, dtype=np.int64)
    c = np.column_stack([np.interp(grid.astype(float), knots, cum[:, i])
                         for i in range(v.shape[1])])
    return grid[1:], np.diff(c, axis=0) / period_us


def _quat_err_rad(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    d = np.abs(np.sum(q1 * q2, axis=1)) / (np.linalg.norm(q1, axis=1) * np.linalg.norm(q2, axis=1))
    return 2.0 * np.arccos(np.clip(d, -1.0, 1.0))


def _down_in_body(q: np.ndarray) -> np.ndarray:
    """(n, 3): the NED down axis in body FRD, R^T e3, from quaternions wxyz."""
    w, x, y, z = q.T
    return np.column_stack((2 * (x * z - w * y), 2 * (y * z + w * x),
                            w * w - x * x - y * y + z * z))


def _yaw(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q.T
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def _roll_pitch(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q.T
    return np.column_stack((np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y)),
                            np.arcsin(np.clip(2 * (w * y - z * x), -1, 1))))


@dataclass(frozen=True)
class ReplayResult:
    """The filter's output at each filter period and its fusion attempts."""
    t_us: np.ndarray                # (n,) log microseconds
    quat_wxyz: np.ndarray           # (n, 4)
    pos_ned_m: np.ndarray           # (n, 3)
    vel_ned_m_s: np.ndarray         # (n, 3)
    ratios: np.ndarray              # (n, 4) vel, pos horizontal, pos vertical, mag (nan: none)
    innovations: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]]   # kind: t, y (n, m), ratio
    t_align_us: int
    sources: Sources
    fused: dict[str, int]
    rejected: dict[str, int]
    diverged: bool


def _origin(log: UlogData) -> tuple[float, float, float] | None:
    if log.ekf2_origin is not None:
        return log.ekf2_origin
    if log.gnss is not None:
        return tuple(float(c) for c in log.gnss.values[0, :3])
    return None


def _field_ned(log: UlogData, decl_rad: float, t0_us: int) -> tuple[float, float, float]:
    """The earth field in NED from the log's own first second at rest: the mean reading levelled
    with the mean specific force's tilt, its horizontal part turned by the declination."""
    a, m = log.accel_m_s2, log.mag_gauss
    sel_a = a.t_us < t0_us + _ALIGN_S * 1e6
    sel_m = m.t_us < t0_us + _ALIGN_S * 1e6
    if not sel_m.any():
        sel_m = slice(0, 10)
    fx, fy, fz = a.values[sel_a].mean(axis=0)
    roll, pitch = math.atan2(-fy, -fz), math.atan2(fx, math.hypot(fy, fz))
    r = np.array(quat_to_dcm(*euler_to_quat(roll, pitch, 0.0)))
    level = r @ m.values[sel_m].mean(axis=0)
    h = math.hypot(level[0], level[1])
    return (h * math.cos(decl_rad), h * math.sin(decl_rad), float(level[2]))


def replay(log: UlogData, *, use_log_params: bool = True) -> ReplayResult:
    """The filter through the log (LogError when the log lacks the IMU)."""
    log.require("gyro_rad_s", "accel_m_s2", for_="trq-ulog-replay")
    given = log.params if use_log_params else {}
    ekf2 = ekf2_record(given, file=log.file)
    extra = extra_values(given)
    decl = math.radians(extra["EKF2_MAG_DECL"])
    period = 1_000_000 // IMU_RATE_HZ
    tg, gyro = resample_imu(log.gyro_rad_s, period)
    ta, accel = resample_imu(log.accel_m_s2, period)
    n = min(len(tg), len(ta))
    start = max(tg[0], ta[0])
    gyro, accel = gyro[np.searchsorted(tg, start):][:n], accel[np.searchsorted(ta, start):][:n]
    grid = np.arange(start, start + period * len(gyro), period, dtype=np.int64)
    n = min(len(grid), len(gyro), len(accel))
    grid, gyro, accel = grid[:n], gyro[:n], accel[:n]
    base = (int(grid[0]) // 10_000) * 10_000 - 10_000     # filter periods stay on their grid
    origin = _origin(log)
    z0 = 0.0
    if log.ekf2_pos_vel is not None:
        i = min(np.searchsorted(log.ekf2_pos_vel.t_us, grid[0]), len(log.ekf2_pos_vel) - 1)
        z0 = float(log.ekf2_pos_vel.values[i, 2])
    has_gnss = log.gnss is not None and origin is not None
    src = Sources(
        imu_rate_hz=IMU_RATE_HZ, gnss=has_gnss, baro=log.baro_alt_m is not None,
        mag=log.mag_gauss is not None, vision=log.vision is not None and not has_gnss,
        mag_field_ned_gauss=(_field_ned(log, decl, int(grid[0]))
                             if log.mag_gauss is not None else (0.0, 0.0, 0.0)),
        init_pos_d_m=z0, mag_declination_rad=decl)
    params = estimator_params(ekf2, src, noaid_noise_m=extra["EKF2_NOAID_NOISE"])
    events: list[tuple[int, object]] = []
    if src.gnss:
        g = log.gnss
        ned = gnss_to_ned(g.values[:, 0], g.values[:, 1], g.values[:, 2], origin)
        delay = params.gnss_delay_us        # EKF2_GPS_DELAY
        for k in range(len(g)):
            t = int(g.t_us[k]) - base
            events.append((t, GnssReading(t - delay, t, ned[k], g.values[k, 3:6].copy(), 3, 10,
                                          float(g.values[k, 6]), float(g.values[k, 7]), 0.0)))
    elif src.vision:
        v = log.vision
        delay = params.ev_delay_us          # EKF2_EV_DELAY
        for k in range(len(v)):
            t = int(v.t_us[k]) - base
            events.append((t, MocapReading(t - delay, t, v.values[k, :3].copy(),
                                           v.values[k, 3:7].copy())))
    else:
        for t in range(int(grid[0]) - base, int(grid[-1]) - base, 1_000_000 // _FAKE_RATE_HZ):
            events.append((t, GnssReading(t, t, np.array((0.0, 0.0, z0)), np.zeros(3), 3, 0,
                                          0.0, 0.0, 0.0)))
    if src.baro:
        b = log.baro_alt_m
        events += [(int(t) - base, BaroReading(int(t) - base, 0.0, float(h), 15.0))
                   for t, h in zip(b.t_us, b.values[:, 0])]
    if src.mag:
        m = log.mag_gauss
        events += [(int(t) - base, MagReading(int(t) - base, m.values[k].copy()))
                   for k, t in enumerate(m.t_us)]
    events.sort(key=lambda e: e[0])
    est = Eskf(params)
    out_t, out_q, out_p, out_v, out_r = [], [], [], [], []
    names = {Aid.GNSS_POS: "gnss_pos", Aid.GNSS_VEL: "gnss_vel", Aid.BARO: "baro",
             Aid.MAG: "mag", Aid.MOCAP_POS: "vision_pos", Aid.MOCAP_ATT: "vision_att"}
    inn: dict[str, list] = {v: [] for v in names.values()}
    last = [None] * len(Aid)
    t_align = None                  # the filter's time at alignment (its first period's start)
    j = 0
    gl, al = gyro.tolist(), accel.tolist()
    for k in range(n):
        t = int(grid[k]) - base
        rs = [ImuReading(t, gl[k], al[k], period)]
        while j < len(events) and events[j][0] <= t:
            rs.append(events[j][1])
            j += 1
        est.step(t, rs)
        if t_align is None and est.aligned:
            t_align = est.t_filter_us + base
        for aid, name in names.items():
            i = est.innovations[aid]
            if i is not None and i is not last[aid]:
                last[aid] = i
                inn[name].append((i.t_us + base, i.innovation.copy(), i.test_ratio))
        if est.aligned and t % 10_000 == 0:
            e = est.output()
            out_t.append(t + base)
            out_q.append(e.quat_wxyz)
            out_p.append(e.pos_ned_m)
            out_v.append(e.vel_ned_m_s)
            out_r.append((e.vel_ratio, e.pos_horiz_ratio, e.pos_vert_ratio, e.mag_ratio))
    if not out_t:
        raise LogError(f"{log.file}: the filter never aligned (the IMU spans "
                       f"{(grid[-1] - grid[0]) / 1e6:.1f} s)")
    e = est.output()
    packed = {k: (np.array([r[0] for r in v], dtype=np.int64),
                  np.array([r[1] for r in v]), np.array([r[2] for r in v]))
              for k, v in inn.items() if v}
    return ReplayResult(np.array(out_t, dtype=np.int64), np.array(out_q), np.array(out_p),
                        np.array(out_v), np.array(out_r, dtype=float), packed,
                        t_align, src,
                        {names[a]: e.fused[a] for a in names}, {names[a]: e.rejected[a]
                                                                for a in names}, e.diverged)


def _stats(x: np.ndarray) -> dict[str, float]:
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if not len(x):
        return {"n": 0}
    return {"n": int(len(x)), "rms": float(np.sqrt(np.mean(x * x))),
            "mean": float(np.mean(x)), "p95": float(np.percentile(np.abs(x), 95)),
            "max": float(np.max(np.abs(x)))}


def _at(t_src: np.ndarray, t_query: np.ndarray) -> np.ndarray:
    """Index of the last source sample at or before each query time."""
    return np.clip(np.searchsorted(t_src, t_query, side="right") - 1, 0, len(t_src) - 1)


def compare(log: UlogData, r: ReplayResult, *, settle_s: float) -> dict:
    """The metrics: the filter against the log's EKF2 from alignment + settle_s on."""
    log.require("ekf2_quat", for_="trq-ulog-replay")
    t0 = r.t_align_us + int(settle_s * 1e6)
    m: dict = {"file": log.file, "settle_s": settle_s, "sources": {
        k: getattr(r.sources, k) for k in ("gnss", "baro", "mag", "vision")},
        "imu_rate_hz": r.sources.imu_rate_hz, "fused": r.fused, "rejected": r.rejected,
        "diverged": r.diverged}
    a = log.ekf2_quat
    sel = (a.t_us >= t0) & (a.t_us <= r.t_us[-1])
    if not sel.any():
        raise LogError(f"{log.file}: no vehicle_attitude sample after the filter's alignment "
                       f"and the {settle_s} s settling")
    i = _at(r.t_us, a.t_us[sel])
    qa, qo = a.values[sel], r.quat_wxyz[i]
    m["span_s"] = float((a.t_us[sel][-1] - a.t_us[sel][0]) / 1e6)
    m["attitude_deg"] = _stats(np.degrees(_quat_err_rad(qa, qo)))
    da, do = _down_in_body(qa), _down_in_body(qo)
    cos = np.sum(da * do, axis=1) / (np.linalg.norm(da, axis=1) * np.linalg.norm(do, axis=1))
    m["tilt_deg"] = _stats(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    dyaw = np.angle(np.exp(1j * (_yaw(qo) - _yaw(qa))))
    m["heading_deg"] = _stats(np.degrees(dyaw))
    m["log_tilt_range_deg"] = float(np.degrees(np.max(np.abs(_roll_pitch(qa)))))
    if log.ekf2_pos_vel is not None:
        lp = log.ekf2_pos_vel
        sel = (lp.t_us >= t0) & (lp.t_us <= r.t_us[-1])
        if sel.any():
            i = _at(r.t_us, lp.t_us[sel])
            dv = r.vel_ned_m_s[i] - lp.values[sel, 3:6]
            dp = r.pos_ned_m[i] - lp.values[sel, 0:3]
            m["velocity_m_s"] = {ax: _stats(dv[:, k]) for k, ax in enumerate("NED")}
            m["velocity_m_s"]["norm"] = _stats(np.linalg.norm(dv, axis=1))
            m["position_m"] = {ax: _stats(dp[:, k]) for k, ax in enumerate("NED")}
            m["position_m"]["horizontal"] = _stats(np.linalg.norm(dp[:, :2], axis=1))
    inn = {}
    for kind, (t, y, ratio) in r.innovations.items():
        s = t >= t0
        row = {"filter": {"rms": [float(v) for v in np.sqrt(np.mean(y[s] ** 2, axis=0))]
                          if s.any() else None,
                          "median_abs": [float(v) for v in np.median(np.abs(y[s]), axis=0)]
                          if s.any() else None,
                          "test_ratio": _stats(ratio[s])}}
        ref = log.ekf2_innovations.get(kind)
        if ref is not None:
            rs = ref.t_us >= t0
            # the median too: EKF2 publishes a kind's innovation before it fuses the kind,
            # values that are not innovations and dominate an RMS
            row["ekf2"] = {"rms": [float(v) for v in np.sqrt(np.mean(ref.values[rs] ** 2,
                                                                      axis=0))]
                           if rs.any() else None,
                           "median_abs": [float(v) for v in np.median(np.abs(ref.values[rs]),
                                                                      axis=0)]
                           if rs.any() else None}
        inn[kind] = row
    m["innovations"] = inn
    if log.ekf2_test_ratios is not None:
        tr = log.ekf2_test_ratios
        s = (tr.t_us >= t0) & (tr.t_us <= r.t_us[-1])
        so = r.t_us >= t0
        # estimator_status publishes the square root of y^2 / (gate^2 S) (EKF2's
        # getInnovationTestStatus); the filter's ratios are compared on that scale
        m["test_ratios"] = {name: {"filter": _stats(np.sqrt(r.ratios[so, k])),
                                   "ekf2": _stats(tr.values[s, k])}
                            for k, name in enumerate(("vel", "pos_horiz", "pos_vert", "mag"))}
    return m


def _plots(log: UlogData, r: ReplayResult) -> dict[str, bytes]:
    import io

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def png(fig) -> bytes:
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=90)
        plt.close(fig)
        return buf.getvalue()

    t_ref = r.t_us[0]
    to = (r.t_us - t_ref) / 1e6
    a = log.ekf2_quat
    sel = a.t_us >= r.t_us[0]
    ta = (a.t_us[sel] - t_ref) / 1e6
    qa = a.values[sel]
    files = {}
    fig, ax = plt.subplots(4, 1, figsize=(9, 9), sharex=True)
    for k, name in enumerate(("roll", "pitch")):
        ax[k].plot(ta, np.degrees(_roll_pitch(qa)[:, k]), label="log's EKF2")
        ax[k].plot(to, np.degrees(_roll_pitch(r.quat_wxyz)[:, k]), "--", label="vehicle's filter")
        ax[k].set_ylabel(f"{name} (deg)")
    ax[2].plot(ta, np.degrees(_yaw(qa)))
    ax[2].plot(to, np.degrees(_yaw(r.quat_wxyz)), "--")
    ax[2].set_ylabel("yaw (deg)")
    i = _at(r.t_us, a.t_us[sel])
    ax[3].plot(ta, np.degrees(_quat_err_rad(qa, r.quat_wxyz[i])), label="attitude")
    da, do = _down_in_body(qa), _down_in_body(r.quat_wxyz[i])
    ax[3].plot(ta, np.degrees(np.arccos(np.clip(np.sum(da * do, axis=1), -1, 1))), label="tilt")
    ax[3].set_ylabel("difference (deg)")
    ax[3].legend()
    ax[0].legend()
    ax[3].set_xlabel("time from the filter's alignment (s)")
    files["attitude.png"] = png(fig)
    if log.ekf2_pos_vel is not None:
        lp = log.ekf2_pos_vel
        sel = lp.t_us >= r.t_us[0]
        tl = (lp.t_us[sel] - t_ref) / 1e6
        fig, ax = plt.subplots(3, 2, figsize=(10, 8), sharex=True)
        for k, axis in enumerate("NED"):
            ax[k, 0].plot(tl, lp.values[sel, k], label="log's EKF2")
            ax[k, 0].plot(to, r.pos_ned_m[:, k], "--", label="vehicle's filter")
            ax[k, 0].set_ylabel(f"p{axis} (m)")
            ax[k, 1].plot(tl, lp.values[sel, 3 + k])
            ax[k, 1].plot(to, r.vel_ned_m_s[:, k], "--")
            ax[k, 1].set_ylabel(f"v{axis} (m/s)")
        ax[0, 0].legend()
        files["position_velocity.png"] = png(fig)
    fig, ax = plt.subplots(4, 1, figsize=(9, 8), sharex=True)
    for k, name in enumerate(("vel", "pos_horiz", "pos_vert", "mag")):
        if log.ekf2_test_ratios is not None:
            tr = log.ekf2_test_ratios
            s = tr.t_us >= r.t_us[0]
            ax[k].plot((tr.t_us[s] - t_ref) / 1e6, tr.values[s, k], label="log's EKF2")
        ax[k].plot(to, np.sqrt(r.ratios[:, k]), "--", label="vehicle's filter")
        ax[k].set_ylabel(f"sqrt {name} ratio")
    ax[0].legend()
    files["test_ratios.png"] = png(fig)
    return files


def _fmt(s: dict, key: str = "rms") -> str:
    return "-" if not s or s.get("n", 0) == 0 else f"{s[key]:.3g}"


def report_md(m: dict) -> str:
    lines = [f"# Replay of `{Path(m['file']).name}` through the vehicle's filter", "",
             f"Sources fed: {', '.join(k for k, v in m['sources'].items() if v) or 'IMU only'}"
             f"{'' if m['sources']['gnss'] or m['sources']['vision'] else ' (EKF2 fake position)'}"
             f"; IMU on a {m['imu_rate_hz']} Hz grid; compared over {m['span_s']:.1f} s from "
             f"{m['settle_s']} s after the filter's alignment. Diverged: {m['diverged']}.", "",
             "| against the log's EKF2 | RMS | p95 | max |", "|---|---|---|---|"]
    for key, label in (("attitude_deg", "attitude (deg)"), ("tilt_deg", "tilt (deg)"),
                       ("heading_deg", "heading (deg)")):
        s = m[key]
        lines.append(f"| {label} | {_fmt(s)} | {_fmt(s, 'p95')} | {_fmt(s, 'max')} |")
    if "velocity_m_s" in m:
        s = m["velocity_m_s"]["norm"]
        lines.append(f"| velocity norm (m/s) | {_fmt(s)} | {_fmt(s, 'p95')} | {_fmt(s, 'max')} |")
        for ax in "NED":
            s = m["position_m"][ax]
            lines.append(f"| position {ax} (m) | {_fmt(s)} | {_fmt(s, 'p95')} | "
                         f"{_fmt(s, 'max')} |")
    lines += ["", f"The log's tilt reaches {m['log_tilt_range_deg']:.1f} deg.", "",
              "| innovations | filter RMS | EKF2 RMS | filter median abs | EKF2 median abs | "
              "filter mean test ratio | fused / rejected |",
              "|---|---|---|---|---|---|---|"]
    for kind, row in m["innovations"].items():
        f = row["filter"]
        e = row.get("ekf2", {})

        def join(v) -> str:
            return ", ".join(f"{x:.3g}" for x in v) if v else "-"
        lines.append(f"| {kind} | {join(f['rms'])} | {join(e.get('rms'))} | "
                     f"{join(f['median_abs'])} | {join(e.get('median_abs'))} | "
                     f"{_fmt(f['test_ratio'], 'mean')} | "
                     f"{m['fused'].get(kind, 0)} / {m['rejected'].get(kind, 0)} |")
    if "test_ratios" in m:
        lines += ["", "estimator_status's test ratios (their square roots of y^2 / (gate^2 S), as "
                  "EKF2 publishes them):", "",
                  "| test ratio | filter mean | EKF2 mean | filter p95 | EKF2 p95 |",
                  "|---|---|---|---|---|"]
        for name, row in m["test_ratios"].items():
            lines.append(f"| {name} | {_fmt(row['filter'], 'mean')} | "
                         f"{_fmt(row['ekf2'], 'mean')} | {_fmt(row['filter'], 'p95')} | "
                         f"{_fmt(row['ekf2'], 'p95')} |")
    lines += ["", "Figures: attitude.png, position_velocity.png, test_ratios.png. The contract: "
              "docs/logs.md.", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="trq-ulog-replay", description="Replay a PX4 ULog's sensors through the vehicle's "
        "EKF2-like filter and compare with the log's own EKF2 (report.md, metrics.json, plots).")
    ap.add_argument("log", type=Path, help="a PX4 .ulg file")
    ap.add_argument("--out", type=Path, required=True, help="the folder to write the report to")
    ap.add_argument("--settle-s", type=float, default=5.0,
                    help="seconds after the filter's alignment left out of the comparison")
    ap.add_argument("--px4-defaults", action="store_true",
                    help="PX4's EKF2 defaults, not the log's EKF2_* parameters")
    args = ap.parse_args(argv)
    try:
        log = read_ulog(args.log)
        log.require("gyro_rad_s", "accel_m_s2", "ekf2_quat", for_="trq-ulog-replay")
        r = replay(log, use_log_params=not args.px4_defaults)
        m = compare(log, r, settle_s=args.settle_s)
    except LogError as exc:
        print(f"trq-ulog-replay: error: {exc}", file=sys.stderr)
        return 2
    files = {"metrics.json": json.dumps(m, indent=2).encode(),
             "report.md": report_md(m).encode(), **_plots(log, r)}
    write_all(args.out, files)
    print(f"tilt RMS {m['tilt_deg']['rms']:.3f} deg, attitude RMS "
          f"{m['attitude_deg']['rms']:.3f} deg; report in {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
