"""The compiled physics tick (sil_vehicle/dynamics/tick.c) against the Python reference: the same
flights, bit for bit. Flights that visit every branch of the tick: on the ground, take-off, idle
clamp and full-throttle clamp, rate limits, tilt limits, gusts, a time-varying motor fault, a motor
switched off, a stuck servo, the quadcopter's locked tilts, a landing, a crash by ground impact and
one by attitude, the gear's contact (touchdown, slide, stick, tip-over), and states, commands and
faults replaced from outside between ticks."""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np
import pytest

from sil_vehicle import compiled
from sil_vehicle.vehicle import ActuatorCommand, Vehicle
from trq_wire.cache import cache_dir

needs_compiler = pytest.mark.skipif(compiled.load_core() is None,
                                    reason="no C compiler: the compiled tick cannot be built")


def pair(sim, **changes):
    """The same vehicle twice: Python reference and compiled tick."""
    sim = sim.with_changes(**changes)
    py = Vehicle(sim.with_changes(physics_core="python"), np.random.default_rng(3))
    cc = Vehicle(sim.with_changes(physics_core="compiled"), np.random.default_rng(3))
    assert (py.core_name, cc.core_name) == ("python", "compiled")
    return py, cc


def both(vehicles, fn):
    for v in vehicles:
        fn(v)


def fly(vehicles, script, ticks, rng):
    """Step both; `script(k, v, r)` may change either vehicle before tick k (same r for both).
    Every state must be equal, field by field, floats bit for bit."""
    states = []
    for k in range(ticks):
        r = rng.random(12)
        for v in vehicles:
            script(k, v, r)
        a, b = (v.step() for v in vehicles)
        assert a == b, f"tick {k}: python {a} != compiled {b}"
        states.append(a)
    return states


def random_command(v, r, trim):
    v.command = ActuatorCommand(tuple(float(trim - 8.0 + 22.0 * r[i]) for i in range(4)),
                                tuple(float(1.2 * (r[4 + i] - 0.5)) for i in range(4)))


@needs_compiler
def test_flight_with_faults_gusts_and_random_commands(sim):
    vehicles = pair(sim, gusts_enabled=True, wind_speed_m_s=6.0, gust_sigma_m_s=1.5)
    trim = sim.vehicle.hover_throttle_pct

    def script(k, v, r):
        if k == 0:
            v.armed = True
        if k % 10 == 0:                          # a new target every control period
            if k < 500:                          # take off straight (clear of the ground)
                v.command = ActuatorCommand((trim + 8.0,) * 4)
            else:
                random_command(v, r, trim)
        if k == 700:
            v.faults = v.faults.with_motor(0, effectiveness=0.7, amplitude=0.2, omega_rad_s=3.0,
                                           phase_rad=0.4)
        if k == 900:
            v.faults = v.faults.with_servo(2, stuck=True, angle_rad=0.2)
        if k == 1100:
            v.faults = v.faults.with_motor(3, off=True)
        if k == 1150:
            v.faults = v.faults.with_motor(3, off=False)
        if k == 1300:                            # a state set from outside (as a test would)
            x = list(v.state.x)
            x[10] = 0.3
            v.state = dataclasses.replace(v.state, x=tuple(x))

    states = fly(vehicles, script, 1600, np.random.default_rng(11))
    airborne = [s for s in states if not s.landed]
    assert len(airborne) > 1200 and min(s.x[2] for s in airborne) < -0.3   # the RK4 ran
    # (the random commands bring it down on its gear, tilted: contact and crash compared too)
    assert any(s.on_ground for s in states[600:])


@needs_compiler
def test_quadcopter_locked_tilts_and_landing(sim, quad):
    vehicles = pair(sim.with_changes(vehicle=quad))
    trim = quad.hover_throttle_pct

    def script(k, v, r):
        if k == 0:
            v.armed = True
        if k % 10 == 0:      # climb 0.6 s, then descend at about 0.4 m/s (a P loop on speed)
            zeta = trim + 10.0 if k < 600 else trim + 10.0 * (v.state.x[5] - 0.4)
            v.command = ActuatorCommand((zeta,) * 4, (0.5, -0.5, 0.5, -0.5))  # tilts: locked
    fly(vehicles, script, 6000, np.random.default_rng(5))
    s = vehicles[0].state
    assert s.landed and not s.crashed and s.tilt_rad == (0.0,) * 4


@needs_compiler
def test_crash_by_impact_and_by_attitude(sim):
    # impact: 20 m up, motors off, armed
    vehicles = pair(sim)

    def drop(v):
        v.armed = True
        x = list(v.state.x)
        x[2] = -20.0
        v.state = dataclasses.replace(v.state, x=tuple(x), landed=False)
    both(vehicles, drop)
    fly(vehicles, lambda k, v, r: None, 3000, np.random.default_rng(0))
    s = vehicles[0].state
    assert s.crashed and s.crash_reason.startswith("ground impact at")

    # attitude: two motors full, two idle
    vehicles = pair(sim)

    def flip(k, v, r):
        if k == 0:
            v.armed = True
            x = list(v.state.x)
            x[2] = -30.0
            v.state = dataclasses.replace(v.state, x=tuple(x), landed=False)
            v.command = ActuatorCommand((100.0, 0.0, 100.0, 0.0))
    fly(vehicles, flip, 1500, np.random.default_rng(0))
    assert vehicles[0].state.crash_reason in ("attitude past the crash limit",) or \
        vehicles[0].state.crash_reason.startswith("ground impact")
    assert vehicles[0].state.crashed


def test_python_core_by_choice(sim):
    assert Vehicle(sim.with_changes(physics_core="python"), np.random.default_rng(0)).core is None


def test_no_compiler_falls_back_to_python_with_a_warning(sim, monkeypatch, tmp_path):
    monkeypatch.setenv("PATH", str(tmp_path))            # no gcc, cc, clang
    monkeypatch.setenv("CC", "no-such-compiler")
    compiled.load_core.cache_clear()
    try:
        with pytest.warns(RuntimeWarning, match="no C compiler"):
            v = Vehicle(sim.with_changes(physics_core="auto"), np.random.default_rng(0))
        assert v.core is None
        v.armed = True
        v.command = ActuatorCommand((sim.vehicle.hover_throttle_pct + 5.0,) * 4)
        for _ in range(200):
            v.step()
        assert v.state.x[2] < 0.0                       # the Python tick flies it
        compiled.load_core.cache_clear()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            with pytest.raises(RuntimeError, match="physics_core: compiled"):
                Vehicle(sim.with_changes(physics_core="compiled"), np.random.default_rng(0))
    finally:
        compiled.load_core.cache_clear()


def test_bad_physics_core_names_the_key(tmp_path):
    from sil_vehicle.config import PARAMS_DIR, ConfigError, load_sim
    bad = tmp_path / "sim.yaml"
    bad.write_text(f"extends: {PARAMS_DIR / 'sim' / 'default.yaml'}\n"
                   f"vehicle: {PARAMS_DIR / 'vehicle' / 'trq.yaml'}\nphysics_core: fortran\n")
    with pytest.raises(ConfigError, match="physics_core.*fortran"):
        load_sim(bad)


@needs_compiler
def test_compiled_tick_is_cached(sim):
    first = compiled.load_core()
    assert first is not None and first.path.exists()
    assert first.path.parent == cache_dir()
    assert math.isfinite(first.path.stat().st_size)


@needs_compiler
def test_ground_contact_touchdown_slide_tip_over_and_rest(sim):
    """The gear's contact in every branch: a tilted touchdown sliding sideways (friction's slip
    and stick), a rebound, rest under a crosswind (the stick region), a take-off, and a
    tip-over; states equal bit for bit."""
    for roll, vel, wind in ((0.15, (0.3, 1.5, 0.8), 8.0), (1.0, (0.0, 3.0, 0.5), 0.0)):
        vehicles = pair(sim, wind_speed_m_s=wind)
        trim = sim.vehicle.hover_throttle_pct

        def place(v, roll=roll, vel=vel):
            x = list(v.state.x)
            x[2] = -0.05
            x[3:6] = vel
            x[6:10] = (math.cos(roll / 2), math.sin(roll / 2), 0.0, 0.0)
            v.state = dataclasses.replace(v.state, x=tuple(x), landed=False, on_ground=False)
        both(vehicles, place)

        def script(k, v, r):
            if k == 1500:
                v.armed = True
                v.command = ActuatorCommand((trim + 10.0,) * 4)
        states = fly(vehicles, script, 2000, np.random.default_rng(1))
        assert any(s.on_ground for s in states)
        if roll > 0.5:
            assert states[-1].crashed
        else:
            assert not states[-1].crashed and not states[-1].on_ground     # took off again
