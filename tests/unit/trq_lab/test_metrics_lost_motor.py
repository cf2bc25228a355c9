"""The lost-motor metrics (trq_lab.metrics.lost_motor_metrics) on a synthetic truth log with
known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest

from trq_lab import metrics


def _log(tilt_deg=10.0):
    """1 kHz from 0 to 6 s: hovering at 5 m, then from 1 s down at 1 m/s, drifting east at
    0.1 m/s and tilted tilt_deg about north from 2 s; on the ground (landed) from 6 s."""
    t_us = np.arange(0, 7_000_001, 1000, dtype=np.int64)
    t = t_us * 1e-6
    down = np.where(t < 1.0, -5.0, np.minimum(-5.0 + (t - 1.0), 0.0))
    vel_d = np.where((t >= 1.0) & (down < 0.0), 1.0, 0.0)
    east = np.where(t < 1.0, 0.0, 0.1 * (np.minimum(t, 6.0) - 1.0))
    half = math.radians(tilt_deg) / 2.0
    tilted = t >= 2.0
    truth = {"t_us": t_us, "pos_n_m": np.zeros_like(t), "pos_e_m": east, "pos_d_m": down,
             "vel_d_m_s": vel_d, "qw": np.where(tilted, math.cos(half), 1.0),
             "qx": np.where(tilted, math.sin(half), 0.0), "qy": np.zeros_like(t),
             "qz": np.zeros_like(t), "landed": (t >= 6.0).astype(float),
             "crashed": np.zeros_like(t)}
    steps = {"stamp_us": t_us[::10], "lost_motor": (t[::10] >= 1.13).astype(float)}
    return truth, steps


def test_the_lost_motor_metrics_of_a_known_descent():
    truth, steps = _log()
    m = metrics.lost_motor_metrics(truth, steps, 1_000_000)
    assert m["max_thrust_tilt_after_fault_deg"] == pytest.approx(10.0)
    assert m["touchdown_tilt_deg"] == pytest.approx(10.0)
    # contact within 2 cm of the ground: at 5.98 s; the last row above it at 1 m/s
    assert m["touchdown_speed_m_s"] == pytest.approx(1.0)
    assert m["descent_rate_m_s"] == pytest.approx(1.0, abs=1e-3)
    assert m["drift_after_fault_m"] == pytest.approx(0.1 * 4.98, abs=1e-3)
    assert m["detection_s"] == pytest.approx(0.13)


def test_no_fault_no_metrics_and_a_tumble_has_no_touchdown():
    truth, steps = _log()
    assert set(metrics.lost_motor_metrics(truth, steps, None).values()) == {None}
    truth["pos_d_m"] = np.full_like(truth["pos_d_m"], -5.0)       # never down
    truth["landed"] = np.zeros_like(truth["landed"])
    truth["crashed"] = (truth["t_us"] >= 3_000_000).astype(float)
    m = metrics.lost_motor_metrics(truth, steps, 1_000_000)
    assert m["touchdown_speed_m_s"] is None and m["descent_rate_m_s"] is None
    assert m["max_thrust_tilt_after_fault_deg"] == pytest.approx(10.0)
