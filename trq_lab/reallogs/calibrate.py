"""`trq-sensing-calibrate LOG --out profile.yaml`: a sensing profile from a log.

Input: a PX4 ULog (.ulg), a static IMU recording (.npz: t_us, gyro_frd_rad_s, accel_frd_m_s2,
rate_hz), or `--static-from PROFILE --duration-s S --seed N`: the vehicle's IMU model of that
profile run at rest (trq_lab.reallogs.allan.static_recording; `--save-recording REC.npz` keeps it).

    1. at rest: the longest span with the motors off (where the log says) whose 1 s windows all
       have a gyro standard deviation below REST_GYRO_STD_RAD_S and a mean specific force within
       REST_ACCEL_TOL_M_S2 of g, at least --min-rest-s long (a LogError otherwise, naming the file)
    2. the overlapping Allan deviation of each gyro and accelerometer axis (allantools) on it:
       noise densities N, bias instabilities B, random walks K (trq_lab.reallogs.allan)
    3. in flight (the motors above FLIGHT_MOTOR_FRACTION): the spectra of the gyro and the
       accelerometer (Welch, 1 s Hann segments), their peaks and each peak's ratio to the rotor's
       rotation frequency where the log has esc_status rpm, and the band's strongest peak per
       1 s window tracked against the rotors' speed (`peak_track`: the harmonic per revolution
       and how much of the peaks' movement the rotors explain); the vibration above
       VIBRATION_BAND_HZ less the white noise's share, scaled to full throttle as the vehicle's
       model takes it (amplitude proportional to thrust: the mean motor output squared)
    4. the profile: `extends:` a built-in (--extends, default gnss) and overrides the IMU's
       densities (N for the noise densities; K for the random walks only when the record is long
       enough for them to show, else the built-in's stay) and, from a flight whose tracked peak
       follows the rotors, the vibration's lines (`imu.vibration.harmonics`, `vibration_lines`:
       `of: rotor, times: n` at the multiple found, the band's vibration shared by the lines;
       else the base's lines stay); validated by the same loader and schema `--sensing PATH`
       uses before it is written. Beside it, PROFILE.calibration.json (every estimate, per axis,
       with the curve, the spectra and why lines were or were not written) and PROFILE.allan.png.
       Nothing is written when any step fails.

The schema has no bias instability field (the vehicle's IMU model has no flicker term): B is in
the calibration file only. The figures: docs/decisions/2026-12-05-ulog-replay-calibration.md.
"""

from __future__ import annotations

import argparse
import io
import json
import math
import sys
from pathlib import Path

import numpy as np
from trq_params import loader

from sil_vehicle.sensors.profile import load_sensing
from sil_vehicle.sensors.truth import STANDARD_GRAVITY_M_S2
from trq_lab.reallogs.allan import AllanFit, allan_fit, model_bias_instability, static_recording
from trq_lab.reallogs.output import write_all
from trq_lab.reallogs.replay import resample_imu
from trq_lab.reallogs.ulog import LogError, Series, read_ulog

N_ROTORS = 4            # the vehicle's rotors (sil_vehicle.sensors.suite.N_ROTORS)

__all__ = ["REST_GYRO_STD_RAD_S", "REST_ACCEL_TOL_M_S2", "FLIGHT_MOTOR_FRACTION",
           "VIBRATION_BAND_HZ", "TRACK_R2_MIN", "HARMONIC_TOL", "Recording", "load_recording",
           "vibration_lines", "calibrate", "main"]

REST_GYRO_STD_RAD_S = 0.02      # a choice: a bench IMU's noise is below, a hand's tremor above
REST_ACCEL_TOL_M_S2 = 0.5       # a choice
FLIGHT_MOTOR_FRACTION = 0.1     # a choice: motors spinning for flight, not idling armed
VIBRATION_BAND_HZ = 20.0        # a choice: above a small multirotor's motion
TRACK_R2_MIN = 0.8              # a choice: a tracked peak the rotors explain (share of variance)
HARMONIC_TOL = 0.1              # a choice: how near a whole multiple of the rotor's frequency
_PEAK_OVER_FLOOR = 10.0         # a peak: a local maximum this many times the median PSD (a choice)
_BUILTIN_PHYSICS_HZ = 1000      # the rate the written profile is validated against (sim default)


class Recording:
    """An IMU's samples on a uniform grid, and what the log says of the motors."""

    def __init__(self, source: str, rate_hz: float, t_us: np.ndarray, gyro: np.ndarray,
                 accel: np.ndarray, motors: Series | None = None, rpm: Series | None = None):
        self.source, self.rate_hz, self.t_us = source, rate_hz, t_us
        self.gyro, self.accel, self.motors, self.rpm = gyro, accel, motors, rpm


def load_recording(path: Path) -> Recording:
    """A ULog or a .npz static recording (LogError naming the file or topic when unusable)."""
    path = Path(path)
    if path.suffix == ".npz":
        if not path.is_file():
            raise LogError(f"{path}: no such file")
        with np.load(path) as z:
            missing = [k for k in ("t_us", "gyro_frd_rad_s", "accel_frd_m_s2", "rate_hz")
                       if k not in z]
            if missing:
                raise LogError(f"{path}: a static recording needs arrays {missing}")
            return Recording(str(path), float(z["rate_hz"]), z["t_us"], z["gyro_frd_rad_s"],
                             z["accel_frd_m_s2"])
    log = read_ulog(path)
    log.require("gyro_rad_s", "accel_m_s2", for_="trq-sensing-calibrate")
    dt = np.median(np.diff(log.gyro_rad_s.t_us))
    period = int(max(1000, round(dt / 1000) * 1000))      # the log's own rate, whole ms
    tg, g = resample_imu(log.gyro_rad_s, period)
    ta, a = resample_imu(log.accel_m_s2, period)
    start = max(tg[0], ta[0])
    g, a = g[np.searchsorted(tg, start):], a[np.searchsorted(ta, start):]
    n = min(len(g), len(a))
    t = start + period * np.arange(n, dtype=np.int64)
    return Recording(str(path), 1e6 / period, t, g[:n], a[:n], log.motor_fraction, log.rotor_rpm)


def _at(s: Series, t: np.ndarray) -> np.ndarray:
    i = np.clip(np.searchsorted(s.t_us, t, side="right") - 1, 0, len(s) - 1)
    v = s.values[i]
    return np.where((t < s.t_us[0])[:, None], 0.0, v)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    d = np.diff(np.concatenate(([0], mask.astype(int), [0])))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1)))


def rest_span(rec: Recording, min_rest_s: float) -> tuple[int, int]:
    """[start, end) sample indices of the longest span at rest (LogError if shorter than
    min_rest_s)."""
    w = max(1, int(round(rec.rate_hz)))           # 1 s windows
    nw = len(rec.gyro) // w
    if nw == 0:
        raise LogError(f"{rec.source}: {len(rec.gyro)} IMU samples, less than a second")
    g = rec.gyro[:nw * w].reshape(nw, w, 3)
    a = rec.accel[:nw * w].reshape(nw, w, 3)
    ok = (g.std(axis=1).max(axis=1) < REST_GYRO_STD_RAD_S) & \
        (np.abs(np.linalg.norm(a.mean(axis=1), axis=1) - STANDARD_GRAVITY_M_S2)
         < REST_ACCEL_TOL_M_S2)
    if rec.motors is not None:
        t_mid = rec.t_us[np.arange(nw) * w + w // 2]
        ok &= _at(rec.motors, t_mid).max(axis=1) < FLIGHT_MOTOR_FRACTION / 2
    runs = _runs(ok)
    best = max(runs, key=lambda r: r[1] - r[0], default=(0, 0))
    if (best[1] - best[0]) < min_rest_s:
        raise LogError(f"{rec.source}: the longest span at rest is {best[1] - best[0]} s, "
                       f"--min-rest-s asks for {min_rest_s:g} s (at rest: motors off, gyro std "
                       f"below {REST_GYRO_STD_RAD_S} rad/s, specific force within "
                       f"{REST_ACCEL_TOL_M_S2} m/s^2 of g, per 1 s window)")
    return best[0] * w, best[1] * w


def _welch(x: np.ndarray, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """One-sided PSD (units^2/Hz) of each column, 1 s Hann segments, half overlapping."""
    n = max(8, int(round(rate_hz)))
    win = np.hanning(n)
    scale = 1.0 / (rate_hz * np.sum(win ** 2))
    starts = range(0, len(x) - n + 1, n // 2)
    psd = np.zeros((n // 2 + 1, x.shape[1]))
    for s in starts:
        seg = x[s:s + n] - x[s:s + n].mean(axis=0)
        psd += np.abs(np.fft.rfft(seg * win[:, None], axis=0)) ** 2
    psd *= scale / max(1, len(starts))
    psd[1:-1] *= 2.0
    return np.fft.rfftfreq(n, 1.0 / rate_hz), psd


def _peaks(f: np.ndarray, p: np.ndarray, k: int = 5) -> list[tuple[float, float]]:
    """The k highest local maxima in the vibration band over _PEAK_OVER_FLOOR x its median."""
    band = f >= VIBRATION_BAND_HZ
    floor = np.median(p[band])
    i = np.flatnonzero((p[1:-1] > p[:-2]) & (p[1:-1] >= p[2:]) & band[1:-1]
                       & (p[1:-1] > _PEAK_OVER_FLOOR * floor)) + 1
    i = i[np.argsort(p[i])[::-1][:k]]
    return [(float(f[j]), float(p[j])) for j in sorted(i)]


def peak_track(x: np.ndarray, rate_hz: float, runs: list[tuple[int, int]],
               rotor_hz: np.ndarray | None, motor: np.ndarray) -> dict:
    """The band's strongest peak in each 1 s window of flight against the rotors' speed there:
    a vibration from the rotors moves with them. With rotor speeds (esc_status) the fit is
    f_peak = h f_rotor (h: the harmonic, per revolution); with motor outputs only, f_peak =
    a u + b. r2: the share of the peaks' variance the fit explains (near 0: not the rotors)."""
    w = max(8, int(round(rate_hz)))
    rows = []
    for a, b in runs:
        for s in range(a, b - w + 1, w):
            f, p = _welch(x[s:s + w], rate_hz)
            band = f >= VIBRATION_BAND_HZ
            total = p.sum(axis=1)
            j = int(np.argmax(np.where(band, total, -1.0)))
            rows.append((float(f[j]), float(total[j] / np.median(total[band])),
                         None if rotor_hz is None else float(rotor_hz[s:s + w].mean()),
                         float(motor[s:s + w].mean())))
    out: dict = {"windows": [dict(zip(("peak_hz", "over_median", "rotor_hz", "motor"), r))
                             for r in rows]}
    if len(rows) < 3:
        return out
    fp = np.array([r[0] for r in rows])
    ss = float(np.sum((fp - fp.mean()) ** 2)) or 1e-12
    if rotor_hz is not None:
        fr = np.array([r[2] for r in rows])
        h = float(fp @ fr / (fr @ fr)) if fr @ fr > 0 else math.nan
        out.update(harmonic_per_rev=h, r2=1.0 - float(np.sum((fp - h * fr) ** 2)) / ss)
    else:
        u = np.array([r[3] for r in rows])
        a, b = np.polyfit(u, fp, 1)
        out.update(hz_per_motor_fraction=float(a), hz_at_zero=float(b),
                   r2=1.0 - float(np.sum((fp - (a * u + b)) ** 2)) / ss)
    return out


def flight_spectra(rec: Recording, fits: dict[str, AllanFit]) -> dict | None:
    """The in-flight spectra, peaks and vibration (None without motor information or flight)."""
    if rec.motors is None:
        return None
    z = _at(rec.motors, rec.t_us).mean(axis=1)
    runs = [r for r in _runs(z > FLIGHT_MOTOR_FRACTION) if r[1] - r[0] >= 2 * rec.rate_hz]
    if not runs:
        return None
    out: dict = {"seconds": float(sum(b - a for a, b in runs) / rec.rate_hz),
                 "mean_motor_fraction": None, "sensors": {}}
    sel = np.concatenate([np.arange(a, b) for a, b in runs])
    zz = z[sel]
    out["mean_motor_fraction"] = float(zz.mean())
    rotor_hz = None
    rotor_series = None                 # per sample, the spinning rotors' mean rotation rate
    if rec.rpm is not None:
        spinning = rec.rpm.values.max(axis=0) > 0          # the ESCs the vehicle has
        if spinning.any():
            rotor_series = _at(Series(rec.rpm.t_us, rec.rpm.values[:, spinning]),
                               rec.t_us).mean(axis=1) / 60.0
            rpm = rotor_series[sel]
            if rpm.max() > 0:
                rotor_hz = float(rpm[rpm > 0].mean())
            else:
                rotor_series = None
    out["rotor_hz"] = rotor_hz
    z2 = float(np.mean(zz ** 2))
    out["mean_motor_squared"] = z2
    for name, x in (("gyro", rec.gyro), ("accel", rec.accel)):
        fs, ps = [], []
        for a, b in runs:
            f, p = _welch(x[a:b], rec.rate_hz)
            fs, ps = f, ps + [p * (b - a)]
        psd = np.sum(ps, axis=0) / len(sel)
        band = fs >= VIBRATION_BAND_HZ
        df = fs[1] - fs[0]
        var_band = psd[band].sum(axis=0) * df                  # per axis
        # the white noise's share of the band: N = sigma / sqrt(rate) (the Allan line, the
        # model's density) is a two-sided density; the one-sided PSD here is 2 N^2
        white = 2.0 * fits[name].n_density ** 2 * band.sum() * df
        vib = np.sqrt(np.maximum(var_band - white, 0.0))
        total = psd.sum(axis=1)
        peaks = _peaks(fs, total)
        out["sensors"][name] = {
            "band_std_per_axis": vib.tolist(),
            "vibration_at_full_throttle": float(np.sqrt(np.mean(vib ** 2)) / z2) if z2 else None,
            "peaks_hz": [{"hz": hz, "psd": pw,
                          "per_rotor_rev": (hz / rotor_hz) if rotor_hz else None}
                         for hz, pw in peaks],
            "nyquist_hz": rec.rate_hz / 2,
            "peak_track": peak_track(x, rec.rate_hz, runs, rotor_series, z)}
    return out


def vibration_lines(spectra: dict | None, period_s: float) -> dict:
    """The profile's `imu.vibration.harmonics` from a flight's peak tracking, or why none.

    A line is found where a sensor's tracked peak follows the rotors (esc_status rpm: r2 at
    least TRACK_R2_MIN) at a whole multiple n of their rotation frequency (within HARMONIC_TOL):
    it becomes `{of: rotor, times: n}`. Each sensor's in-band vibration per axis, scaled to full
    throttle (`band_std_per_axis` / the mean squared motor output, as the model's amplitude
    scales with thrust), is shared equally by the lines found (a choice), each line one rotor's
    amplitude with N_ROTORS rotors' lines adding in power (RMS a sqrt(N_ROTORS / 2) per line), and
    divided by the log's own averaging over its sample interval at the line's frequency (|sinc|:
    the log's samples are the IMU's mean over `period_s`, the model's lines are before it).
    Returns {"harmonics": [...] or None, "found": [...], "why": text}."""
    if spectra is None:
        return {"harmonics": None, "found": [], "why": "no flight in the log"}
    if spectra.get("rotor_hz") is None:
        return {"harmonics": None, "found": [], "why": "no rotor speed (esc_status rpm) in the "
                "log: a peak cannot be tied to a multiple of the rotor's frequency"}
    found = []
    for name, d in spectra["sensors"].items():
        t = d["peak_track"]
        h, r2 = t.get("harmonic_per_rev"), t.get("r2")
        if h is None or r2 is None or not math.isfinite(h):
            continue
        n = int(round(h))
        if r2 >= TRACK_R2_MIN and n >= 1 and abs(h - n) <= HARMONIC_TOL:
            found.append({"sensor": name, "harmonic_per_rev": h, "r2": r2, "times": n})
    times = sorted({f["times"] for f in found})
    if not times:
        return {"harmonics": None, "found": [], "why": "no tracked peak follows the rotors "
                f"(r2 below {TRACK_R2_MIN} or not within {HARMONIC_TOL} of a whole multiple)"}
    z2 = spectra["mean_motor_squared"]
    amp = {}
    for name, d in spectra["sensors"].items():
        full = np.asarray(d["band_std_per_axis"]) / z2
        amp[name] = full * math.sqrt(2.0 / (N_ROTORS * len(times)))
    lines = []
    for n in times:
        x = math.pi * n * spectra["rotor_hz"] * period_s
        gain = abs(math.sin(x) / x) if x else 1.0
        lines.append({"of": "rotor", "times": n,
                      "accel_m_s2": [float(f"{v / gain:.4g}") for v in amp["accel"]],
                      "gyro_rad_s": [float(f"{v / gain:.4g}") for v in amp["gyro"]]})
    return {"harmonics": lines, "found": found,
            "why": f"{len(found)} tracked peak(s) follow the rotors"}


def _long_enough(fit: AllanFit) -> bool:
    """The bias random walk is read off the record: its longest tau is at least three times the
    curve's minimum, sqrt(3) N / K, where the random walk starts to dominate (a choice)."""
    n, k = fit.mean("n_density"), fit.mean("k_random_walk")
    return k > 0 and float(fit.taus_s[-1]) >= 3.0 * math.sqrt(3.0) * n / k


def calibrate(rec: Recording, *, extends: str, name: str, min_rest_s: float,
              base_smear_hz: float = 1.0) -> tuple[dict, dict]:
    """(the profile's mapping, the calibration record). `base_smear_hz`: the written lines' width
    (`main` passes the base profile's, or the built-in gnss profile's when the base has none)."""
    a, b = rest_span(rec, min_rest_s)
    fits = {"gyro": allan_fit(rec.gyro[a:b], rec.rate_hz),
            "accel": allan_fit(rec.accel[a:b], rec.rate_hz)}
    spectra = flight_spectra(rec, fits)
    imu: dict = {}
    keys = {"gyro": ("gyro_noise_density_rad_s_rthz", "gyro_bias_random_walk_rad_s2_rthz"),
            "accel": ("accel_noise_density_m_s2_rthz", "accel_bias_random_walk_m_s3_rthz")}
    record: dict = {"source": rec.source, "rate_hz": rec.rate_hz,
                    "rest_s": (b - a) / rec.rate_hz, "extends": extends, "imu": {}}
    for s, fit in fits.items():
        nk, kk = keys[s]
        imu[nk] = float(f"{fit.mean('n_density'):.4g}")
        long_enough = _long_enough(fit)
        if long_enough:
            imu[kk] = float(f"{fit.mean('k_random_walk'):.4g}")
        record["imu"][s] = {
            "n_density": fit.n_density.tolist(), "k_random_walk": fit.k_random_walk.tolist(),
            "k_written": long_enough, "bias_instability": fit.bias_instability.tolist(),
            "bias_instability_tau_s": fit.tau_min_s.tolist(),
            # the minimum at the longest tau: the curve had not turned up yet, B a bound above
            "bias_instability_upper_bound": bool(np.any(fit.tau_min_s >= fit.taus_s[-1])),
            "taus_s": fit.taus_s.tolist(), "adev": fit.adev.tolist()}
    record["flight"] = spectra
    vib = vibration_lines(spectra, 1.0 / rec.rate_hz)
    if vib["harmonics"] is not None:
        imu["vibration"] = {"harmonics": vib["harmonics"], "smear_hz": base_smear_hz}
    record["vibration"] = {**vib, "written": vib["harmonics"] is not None,
                           "smear_hz": base_smear_hz if vib["harmonics"] is not None else None}
    base = extends if extends.startswith("builtin:") or "/" in extends or extends.endswith(
        ".yaml") else f"builtin:sensing/{extends}"
    profile = {"extends": base, "name": name,
               "description": f"calibrated by trq-sensing-calibrate from {Path(rec.source).name}",
               "imu": imu}
    return profile, record


def _allan_png(record: dict) -> bytes:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(1, 2, figsize=(10, 4))
    for k, s in enumerate(("gyro", "accel")):
        r = record["imu"][s]
        t, ad = np.array(r["taus_s"]), np.array(r["adev"])
        for i, axis in enumerate("xyz"):
            ax[k].loglog(t, ad[:, i], label=axis)
        n, kk = np.mean(r["n_density"]), np.mean(r["k_random_walk"])
        ax[k].loglog(t, np.sqrt(n * n / t + kk * kk * t / 3), "k--", label="N, K fit")
        ax[k].set_title(s)
        ax[k].set_xlabel("tau (s)")
        ax[k].legend()
    ax[0].set_ylabel("Allan deviation")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    plt.close(fig)
    return buf.getvalue()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="trq-sensing-calibrate", description="Calibrate a sensing profile (its IMU's "
        "noise densities, random walks and vibration) from a PX4 ULog or a static IMU "
        "recording; writes PROFILE.yaml (flown with --sensing PATH), "
        "PROFILE.calibration.json and PROFILE.allan.png.")
    ap.add_argument("log", type=Path, nargs="?", help="a .ulg log or a .npz static recording")
    ap.add_argument("--out", type=Path, required=True, help="the profile file to write (.yaml)")
    ap.add_argument("--extends", default="gnss",
                    help="the profile the calibrated one extends (a built-in name or a path)")
    ap.add_argument("--name", help="the profile's name (default: the --out file's stem)")
    ap.add_argument("--min-rest-s", type=float, default=10.0,
                    help="the shortest span at rest the Allan deviation is taken on")
    ap.add_argument("--static-from", metavar="PROFILE",
                    help="instead of a log: this profile's IMU model at rest")
    ap.add_argument("--duration-s", type=float, default=3600.0,
                    help="with --static-from: the recording's length")
    ap.add_argument("--seed", type=int, default=0, help="with --static-from: the seed")
    ap.add_argument("--save-recording", type=Path, help="with --static-from: keep it (.npz)")
    args = ap.parse_args(argv)
    if (args.log is None) == (args.static_from is None):
        ap.error("give a LOG or --static-from PROFILE (one of them)")
    out = args.out
    if out.suffix not in (".yaml", ".yml"):
        ap.error(f"--out {out}: a .yaml file expected")
    try:
        if args.static_from is not None:
            imu = load_sensing(args.static_from, _BUILTIN_PHYSICS_HZ).imu
            if imu is None:
                raise LogError(f"--static-from {args.static_from}: the profile has no IMU")
            t, g, a = static_recording(imu, args.duration_s, args.seed)
            rec = Recording(f"static:{args.static_from}:seed{args.seed}:{args.duration_s:g}s",
                            float(imu.rate_hz), t, g, a)
        else:
            rec = load_recording(args.log)
        profile, record = calibrate(rec, extends=args.extends, name=args.name or out.stem,
                                    min_rest_s=args.min_rest_s,
                                    base_smear_hz=_base_smear_hz(args.extends, out))
        if args.static_from is not None:
            ref = load_sensing(args.static_from, _BUILTIN_PHYSICS_HZ).imu
            record["reference"] = {
                "gyro": {"n_density": ref.gyro_noise_density_rad_s_rthz,
                         "k_random_walk": ref.gyro_bias_random_walk_rad_s2_rthz,
                         "bias_instability": model_bias_instability(
                             ref.gyro_noise_density_rad_s_rthz,
                             ref.gyro_bias_random_walk_rad_s2_rthz)},
                "accel": {"n_density": ref.accel_noise_density_m_s2_rthz,
                          "k_random_walk": ref.accel_bias_random_walk_m_s3_rthz,
                          "bias_instability": model_bias_instability(
                              ref.accel_noise_density_m_s2_rthz,
                              ref.accel_bias_random_walk_m_s3_rthz)}}
        header = (f"# Sensing profile calibrated by trq-sensing-calibrate from {rec.source}.\n"
                  f"# The estimates per axis, the Allan deviation and the flight's spectra: "
                  f"{out.stem}.calibration.json beside this file.\n")
        text = header + loader.dump(profile)
        _validate(text, out)
    except LogError as exc:
        print(f"trq-sensing-calibrate: error: {exc}", file=sys.stderr)
        return 2
    files = {out.name: text.encode(),
             f"{out.stem}.calibration.json": json.dumps(record, indent=1).encode(),
             f"{out.stem}.allan.png": _allan_png(record)}
    if args.save_recording is not None:
        buf = io.BytesIO()
        np.savez_compressed(buf, t_us=rec.t_us, gyro_frd_rad_s=rec.gyro,
                            accel_frd_m_s2=rec.accel, rate_hz=rec.rate_hz)
        files[args.save_recording.name] = buf.getvalue()
        if args.save_recording.parent.resolve() != out.parent.resolve():
            write_all(args.save_recording.parent, {args.save_recording.name:
                                                   files.pop(args.save_recording.name)})
    write_all(out.parent, files)
    for s in ("gyro", "accel"):
        r = record["imu"][s]
        print(f"{s}: N {np.sqrt(np.mean(np.square(r['n_density']))):.4g}, B "
              f"{np.sqrt(np.mean(np.square(r['bias_instability']))):.4g}, K "
              f"{np.sqrt(np.mean(np.square(r['k_random_walk']))):.4g}"
              f"{'' if r['k_written'] else ' (record too short: not written)'}")
    print(f"wrote {out}")
    return 0


def _base_smear_hz(extends: str, out: Path) -> float:
    """The base profile's vibration line width (the built-in gnss profile's if it has none)."""
    if extends.startswith("builtin:sensing/"):
        ref = extends.removeprefix("builtin:sensing/")
    elif "/" in extends or extends.endswith((".yaml", ".yml")):
        ref = str(out.parent / extends)         # as the written `extends:` resolves
    else:
        ref = extends
    try:
        imu = load_sensing(ref, _BUILTIN_PHYSICS_HZ).imu
    except ValueError as exc:
        raise LogError(f"--extends {extends}: {exc}") from exc
    if imu is None or imu.vibration is None:
        imu = load_sensing("gnss", _BUILTIN_PHYSICS_HZ).imu
    return imu.vibration.smear_hz


def _validate(text: str, out: Path) -> None:
    """The profile through the loader and schema `--sensing PATH` uses, from a temporary file
    beside `out` (so a relative `extends:` resolves as it will)."""
    import os
    import tempfile

    folder = out.parent if out.parent.exists() else Path(tempfile.gettempdir())
    fd, tmp = tempfile.mkstemp(suffix=".yaml", prefix=".calibrated.", dir=folder)
    try:
        with os.fdopen(fd, "w") as fh:
            fh.write(text)
        try:
            load_sensing(tmp, _BUILTIN_PHYSICS_HZ)
        except ValueError as exc:          # trq_params.ConfigError is one
            raise LogError(f"{out}: the calibrated profile does not validate: {exc}") from exc
    finally:
        os.unlink(tmp)


if __name__ == "__main__":
    sys.exit(main())
