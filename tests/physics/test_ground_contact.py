"""The ground as forces (sil_vehicle.dynamics.contact, docs/simulator.md): resting equilibrium,
a drop settling on the spring-damper with its peak deceleration bounded, friction stopping a
slide, tip-over and impact crashes."""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from sil_vehicle.dynamics.contact import contact_wrench, feet_ne_m
from sil_vehicle.frames import euler_to_quat, tilt_from_vertical
from sil_vehicle.vehicle import Vehicle


def vehicle(sim, down_m=0.0, vel=(0.0, 0.0, 0.0), euler=(0.0, 0.0, 0.0), **gear_changes):
    if gear_changes:
        vp = dataclasses.replace(sim.vehicle, **gear_changes)
        sim = sim.with_changes(vehicle=vp)
    v = Vehicle(sim, np.random.default_rng(0))
    x = list(v.state.x)
    x[2] = down_m
    x[3:6] = vel
    x[6:10] = euler_to_quat(*euler)
    v.state = dataclasses.replace(v.state, x=tuple(x), landed=False, on_ground=down_m >= 0.0)
    return v


def run(v, ticks):
    return [v.step() for _ in range(ticks)]


def test_resting_equilibrium_carries_the_weight_and_does_not_drift(sim):
    vp = sim.vehicle
    v = Vehicle(sim, np.random.default_rng(0))
    f = contact_wrench(v.state.x, vp.gear, feet_ne_m(v.state.x, vp.gear))
    assert abs(f[2] + vp.mass_kg * vp.gravity_m_s2) < 1e-9          # normal forces = weight
    assert max(map(abs, f[0:2] + f[3:6])) < 1e-12
    states = run(v, 5000)                                            # 5 s disarmed
    assert all(s.on_ground and s.landed and not s.crashed for s in states)
    end = states[-1]
    assert max(map(abs, end.x[0:6])) < 1e-12 and max(map(abs, end.x[10:13])) < 1e-12


def test_a_drop_settles_in_tens_of_ms_with_the_spring_dampers_peak(sim):
    vp = sim.vehicle
    gear = vp.gear
    n = len(gear.points_frd_m)
    omega = math.sqrt(n * gear.stiffness_N_m / vp.mass_kg)
    zeta = n * gear.damping_N_s_m / (2.0 * vp.mass_kg * omega)
    assert 0.6 < zeta < 0.8                                          # the stated damping ratio
    v = vehicle(sim, -0.05)                                          # about 1 m/s at contact
    states = run(v, 600)
    first = next(k for k, s in enumerate(states) if s.on_ground)
    v0 = states[first].touchdown_speed_m_s
    assert abs(v0 - math.sqrt(2 * vp.gravity_m_s2 * 0.05)) < 0.02
    # linear spring-damper from zero depth at v0: for zeta > 0.5 the largest deceleration is the
    # damper's at contact, n c v0 / m, less gravity; one 1 ms tick averages it a little down
    bound = n * gear.damping_N_s_m * v0 / vp.mass_kg - vp.gravity_m_s2
    accel = np.diff([s.x[5] for s in states]) / (sim.dt_us * 1e-6)
    assert 0.8 * bound < -accel.min() <= 1.01 * bound
    settled = first + 80                                             # 80 ms after contact
    assert all(abs(s.x[2]) < 5e-4 and abs(s.x[5]) < 0.01 for s in states[settled:])
    assert states[-1].landed and not states[-1].crashed
    assert max(s.x[2] for s in states) < 0.01                        # the gear's compression


def test_friction_stops_a_slide_and_it_then_rests(sim):
    v = vehicle(sim, 0.0, vel=(1.0, 0.0, 0.0))
    states = run(v, 1500)
    mu, g = sim.vehicle.gear.friction, sim.vehicle.gravity_m_s2
    stop = next(k for k, s in enumerate(states) if s.x[3] < 1e-3)
    assert abs(stop * 1e-3 - 1.0 / (mu * g)) < 0.01                 # Coulomb: t = v / (mu g)
    assert abs(states[stop].x[0] - 1.0 / (2 * mu * g)) < 0.005      # d = v^2 / (2 mu g)
    rest = states[-1000:]
    assert abs(rest[-1].x[0] - rest[0].x[0]) < 1e-4                  # no creep
    assert rest[-1].landed


def test_tilted_on_the_gear_levels_itself_or_tips_over_past_the_gear(sim):
    tip = sim.vehicle.tip_over_rad
    for roll, crashes in ((math.degrees(tip) - 10.0, False), (math.degrees(tip) + 5.0, True)):
        r = math.radians(roll)
        v = vehicle(sim, -0.01 - 0.12 * math.sin(r), euler=(r, 0.0, 0.0))
        end = run(v, 1500)[-1]
        assert end.crashed == crashes, roll
        if crashes:
            assert end.crash_reason.startswith("tipped over")
        else:
            assert tilt_from_vertical(*end.x[6:10]) < 1e-3 and end.landed


def test_a_sideways_touchdown_on_a_grippy_ground_tips_over(sim):
    # friction above the gear's half-width over height (tan of the tip-over angle): it trips
    v = vehicle(sim, -0.02, vel=(0.0, 4.0, 0.5), gear_friction=2.0)
    end = run(v, 1000)[-1]
    # it trips over a foot; whether the tilt passes the gear's tip-over angle with a foot on the
    # ground or the vehicle vaults over in the air first, it is a crash
    assert end.crashed and end.crash_reason.startswith(("tipped over", "attitude past"))
    v = vehicle(sim, -0.02, vel=(0.0, 4.0, 0.5))                     # mu 0.5: it slides
    end = run(v, 1500)[-1]
    assert not end.crashed and end.landed


def test_impact_speed_is_recorded_and_judged(sim):
    v = vehicle(sim, -0.5)                                           # 3.1 m/s > 2.5 m/s
    states = run(v, 600)
    s = next(s for s in states if s.on_ground)
    assert abs(s.touchdown_speed_m_s - math.sqrt(2 * 9.80665 * 0.5)) < 0.02
    assert s.crashed and s.crash_reason.startswith("ground impact at 3.1")
    assert s.touchdown_tilt_rad == 0.0


def test_a_crosswind_below_breakaway_does_not_make_it_creep(sim):
    """8 m/s of wind on the vehicle at rest: 2 N of drag against mu m g = 10 N. The stick anchors
    hold it: it shifts on its feet's springs by F / (n k_t), and pitches on the normal springs by
    F h / (k sum x^2) (the drag acts at the centre of mass, h above the feet), and stays there."""
    v = Vehicle(sim.with_changes(wind_speed_m_s=8.0, wind_from_deg=0.0), np.random.default_rng(0))
    states = run(v, 5000)
    gear = sim.vehicle.gear
    drag = 0.03125 * 8.0 ** 2
    h = gear.points_frd_m[0][2]
    pitch = drag * h / sum(gear.stiffness_N_m * p[0] ** 2 for p in gear.points_frd_m)
    lean = drag / (len(gear.points_frd_m) * gear.stick_stiffness_N_m) + h * pitch
    assert abs(states[999].x[0] + lean) < 0.05 * lean               # blown south, by the lean
    assert abs(states[-1].x[0] - states[999].x[0]) < 1e-7           # and no further in 4 s
    assert all(s.landed for s in states[200:])


def test_a_fall_that_reaches_into_the_ground_in_one_tick_anchors_where_it_touches(sim):
    """A tumbling fall whose lowest gear point points straight down: the tick begins out of the
    ground's reach (no anchors) and ends with that point in the ground. The points anchor where
    they touch and the tick is judged (an impact at 5 m/s: a crash); it raised an IndexError,
    which killed a campaign's flight (trq_nmpc_eso, motor 2 lost)."""
    gear = sim.vehicle.gear
    p = np.asarray(gear.points_frd_m[0], float)
    p /= np.linalg.norm(p)
    axis = np.cross(p, [0.0, 0.0, 1.0])                   # turn the point onto world down
    angle = math.acos(float(p[2]))
    axis /= np.linalg.norm(axis)
    quat = (math.cos(angle / 2), *(math.sin(angle / 2) * axis))
    v = vehicle(sim, gear.reach_down_m - 0.001, vel=(0.0, 0.0, 5.0))
    x = list(v.state.x)
    x[6:10] = quat
    v.state = dataclasses.replace(v.state, x=tuple(x), anchors_ne_m=())
    s = v.step()
    assert s.on_ground and s.crashed and "impact" in s.crash_reason
    assert s.anchors_ne_m == feet_ne_m(s.x, gear)
