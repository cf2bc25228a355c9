"""The estimator's per-period checks (sil_vehicle.estimator.eskf) against their plain NumPy
statements, on the cases a flight rarely meets: non-finite entries, sums that overflow,
negative and oversized variances; NaN, signed-zero and negative test ratios."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sil_vehicle.estimator import derivation as d
from sil_vehicle.estimator.eskf import Aid, Eskf, Innovation
from sil_vehicle.estimator.params import EstimatorParams
from sil_vehicle.sensors.profile import load_sensing


@pytest.fixture(scope="module")
def est() -> Eskf:
    return Eskf(EstimatorParams.from_profile(load_sensing("rtk", 1000)))


def diverged_reference(x: np.ndarray, P: np.ndarray, max_var: float) -> bool:
    diag = np.diag(P)
    return bool(not (np.isfinite(x).all() and np.isfinite(P).all())
                or (diag < 0.0).any() or (diag > max_var).any())


def cases(max_var: float):
    rng = np.random.default_rng(5)
    x0 = rng.standard_normal(d.NX)
    a = rng.standard_normal((d.NDX, d.NDX))
    P0 = a @ a.T * 1e-3
    yield x0, P0                                        # healthy
    for value in (math.nan, math.inf, -math.inf):
        for where in ("x", "P_off", "P_diag"):
            x, P = x0.copy(), P0.copy()
            if where == "x":
                x[7] = value
            elif where == "P_off":
                P[3, 11] = value
            else:
                P[5, 5] = value
            yield x, P
    x, P = x0.copy(), P0.copy()
    P[1, 2], P[2, 1] = math.inf, -math.inf              # a sum that is nan
    yield x, P
    x, P = x0.copy(), P0.copy()
    P[0, 4] = P[4, 0] = 1.7e308                         # finite entries whose sum overflows
    yield x, P
    x, P = x0.copy(), P0.copy()
    x[0] = x[1] = 1.7e308
    yield x, P
    x, P = x0.copy(), P0.copy()
    P[4, 4] = -1e-12                                    # a negative variance
    yield x, P
    x, P = x0.copy(), P0.copy()
    P[9, 9] = max_var * 1.0000001                       # above max_var
    yield x, P
    x, P = x0.copy(), P0.copy()
    P[9, 9] = max_var                                   # at it
    yield x, P


def test_divergence_check_equals_the_entrywise_one(est):
    max_var = est.params.max_var
    n = 0
    for x, P in cases(max_var):
        est.x, est.P = x, P
        assert est._check_divergence() == diverged_reference(x, P, max_var), n
        n += 1
    assert n == 16


def status_reference(inn) -> tuple[float, float, float, float]:
    """ESTIMATOR_STATUS's ratios as they were first written: NumPy maxima over axis slices."""
    def worst(*parts) -> float:
        vals = [float(inn[a].axis_ratios[sl].max()) for a, sl in parts if inn[a] is not None]
        return max(vals) if vals else math.nan
    h, v, a = slice(0, 2), slice(2, 3), slice(0, 3)
    return (worst((Aid.GNSS_VEL, a)), worst((Aid.MOCAP_POS, h), (Aid.GNSS_POS, h)),
            worst((Aid.MOCAP_POS, v), (Aid.GNSS_POS, v), (Aid.BARO, a)),
            worst((Aid.MAG, a)))


def innovation(aid: Aid, axes) -> Innovation:
    axes = np.array(axes, dtype=float)
    return Innovation(aid, 0, axes, axes, float(axes.max()), True, axes)


def test_status_ratios_equal_the_axis_maxima(est):
    rng = np.random.default_rng(8)
    specials = (math.nan, 0.0, -0.0, -1.5, math.inf, 2.0)
    for k in range(400):
        inn = [None] * len(Aid)
        for aid in Aid:
            if rng.random() < 0.25:
                continue
            m = 1 if aid == Aid.BARO else 3
            axes = rng.exponential(size=m)
            for i in range(m):
                if rng.random() < 0.3:
                    axes[i] = specials[rng.integers(len(specials))]
            inn[aid] = innovation(aid, axes)
        est.innovations = inn
        got, want = est._status_ratios(), status_reference(inn)
        assert np.array(got).tobytes() == np.array(want).tobytes(), (k, got, want)
