"""Ocp.pack and Ocp.unpack (trq_offboard/nmpc/ocp.py) through the stage views against their
specification written with the OCP's index arrays (s_index, v_index), in every stage layout:
the same floats, to the bit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from trq_offboard.allocation import Allocator
from trq_offboard.config import load_controller
from trq_offboard.model import PredictionModel
from trq_offboard.nmpc.ocp import Ocp

from conftest import ROOT

CTRL = ROOT / "params" / "controller"


def _ocp(name, actuator_states):
    cfg = dataclasses.replace(load_controller(CTRL / f"{name}.yaml"),
                              actuator_states=actuator_states)
    alloc = Allocator(cfg.vehicle)
    return Ocp.build(cfg, PredictionModel(cfg.vehicle)), alloc.command_vector(alloc.hover())


def _pack_spec(o, x_plan, u_plan, alpha_prev, y0):
    """pack by index arrays: s_k = [x_k, tilt_k (TRQ), lags], v_k the inputs."""
    w = np.zeros(o.lbw.size)
    if o.tilting:
        tilts = np.vstack([np.reshape(alpha_prev, (1, 4)), u_plan[:, 0:4]])
        s_main = np.hstack([x_plan, tilts])
        w[o.v_index] = np.hstack([np.diff(tilts, axis=0) / o.step_s, u_plan[:, 4:8] / 100.0])
    else:
        s_main = x_plan
        w[o.v_index] = u_plan / o.u_scale
    if o.n_lag:
        ys = [np.asarray(y0, float) / o.u_scale]
        for u in u_plan / o.u_scale:
            ys.append(ys[-1] + o.lag_gain * (u - ys[-1]))
        s_main = np.hstack([s_main, np.array(ys)])
    w[o.s_index] = s_main
    return w


def _unpack_spec(o, w):
    s, v = w[o.s_index], w[o.v_index]
    u = (np.hstack([s[1:, o.nx:o.nx + 4], 100.0 * v[:, 4:8]]) if o.tilting
         else v * o.u_scale)
    return u, s[:, 0:o.nx]


@pytest.mark.parametrize("name,actuator_states", [
    ("trq_nmpc_eso", "off"), ("trq_nmpc_eso", "on"), ("quad_nmpc", "off"), ("quad_nmpc", "on")])
def test_pack_and_unpack_are_their_index_specification(name, actuator_states):
    o, u_trim = _ocp(name, actuator_states)
    N = o.n_steps
    nz = o.ns + o.nv
    assert o.lbw.size == N * nz + o.ns                 # stage-major: the views' premise
    np.testing.assert_array_equal(o.s_index, np.arange(N + 1)[:, None] * nz + np.arange(o.ns))
    assert o.stage_major()
    rng = np.random.default_rng(11)
    for _ in range(20):
        x_plan = rng.normal(size=(N + 1, 12))
        u_plan = u_trim + rng.normal(size=(N, o.nu)) * np.where(np.arange(o.nu) < 4, 0.1, 5.0)
        alpha_prev = rng.normal(size=4) * 0.1
        y0 = u_trim + rng.normal(size=o.nu)
        w = o.pack(x_plan, u_plan, alpha_prev, y0 if o.n_lag else None)
        want = _pack_spec(o, x_plan, u_plan, alpha_prev, y0)
        assert w.tobytes() == want.tobytes()
        w_any = rng.normal(size=w.size)                # any w, not only a packed one
        for got, spec in zip(o.unpack(w_any), _unpack_spec(o, w_any)):
            assert got.shape == spec.shape and got.tobytes() == spec.tobytes()


@pytest.mark.parametrize("name,actuator_states", [
    ("trq_nmpc_eso", "off"), ("trq_nmpc_eso", "on"), ("quad_nmpc", "off")])
def test_throttle_scale_sets_the_throttles_bounds_by_index(name, actuator_states):
    """set_throttle_scale through the stage views: every stage's throttle bounds scaled by e
    and nothing else moved, as the index arrays say, after one scale and after another."""
    o, _ = _ocp(name, actuator_states)
    lo0, hi0 = o.lbw.copy(), o.ubw.copy()
    idx = o.v_index[:, 4:8] if o.tilting else o.v_index[:, 0:4]
    for e in (np.array([0.5, 1.0, 0.75, 0.25]), np.array([1.0, 0.9, 1.0, 0.3])):
        o.set_throttle_scale(e)
        want_lo, want_hi = lo0.copy(), hi0.copy()
        want_lo[idx] = lo0[idx] * e
        want_hi[idx] = hi0[idx] * e
        assert np.array_equal(o.lbw, want_lo) and np.array_equal(o.ubw, want_hi)
    assert o._c_views is not None                  # the views served (w stage by stage)
