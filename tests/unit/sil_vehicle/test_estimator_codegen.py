"""The estimator's compiled functions (sil_vehicle.estimator.codegen) compute what CasADi's
interpreter computes, and one library serves every function."""

from __future__ import annotations

import numpy as np

from sil_vehicle.estimator import derivation as d
from sil_vehicle.estimator.codegen import load


def test_compiled_equals_interpreted():
    fns = d.functions(9.80665)
    compiled, how = load(fns)
    interpreted, how_i = load(fns, enabled=False)
    assert how in ("compiled", "cached") and how_i == "interpreted"
    rng = np.random.default_rng(0)
    x = rng.normal(size=d.NX)
    x[6:10] /= np.linalg.norm(x[6:10])
    A = rng.normal(size=(d.NDX, d.NDX))
    P = A @ A.T
    args = {"predict": (x, P, rng.normal(size=3), rng.normal(size=3), 0.01,
                        np.array((0.99, 0.97, 1.3)), rng.uniform(0, 1e-3, d.NQD)),
            "fuse_mag": (x, P, rng.normal(size=3), np.full(3, 0.01), rng.normal(size=3)),
            "h_baro": (x, x[6:10], np.zeros(3))}
    for name, a in args.items():
        for got, want in zip(compiled[name](*a), interpreted[name](*a)):
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
            assert got.shape == want.shape


def test_outputs_are_dense_and_shaped():
    calls, _ = load(d.functions(9.80665))
    x = np.zeros(d.NX)
    x[6] = 1.0
    h, H = calls["h_mocap_pos"](x, x[6:10], np.zeros(3))
    assert h.shape == (3, 1) and H.shape == (3, d.NDX)
    np.testing.assert_array_equal(H[:, :3], np.eye(3))
    np.testing.assert_array_equal(H[:, 3:], 0.0)
