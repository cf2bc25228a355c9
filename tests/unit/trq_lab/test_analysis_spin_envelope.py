"""trq-envelope --spin: the spinning (relaxed hover) equilibria of a lost motor, checked against
the plant's own functions (rotors.body_wrench, rigid_body.derivative, the Vehicle's tick)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from sil_vehicle.dynamics.rigid_body import derivative
from sil_vehicle.dynamics.rotors import body_wrench
from sil_vehicle.frames import quat_to_dcm
from trq_lab.analysis import envelope, spin_envelope as se

MOTOR1_LOST = [0.0, 1.0, 1.0, 1.0]


@pytest.fixture(scope="module")
def spin20(trq):
    return se.solve(trq, MOTOR1_LOST, spin_rad_s=20.0)


def test_motor1_lost_spinning_hover_is_an_equilibrium_of_the_plant(trq, spin20):
    eq = spin20
    assert eq.feasible and eq.descent_m_s == 0.0 and eq.margin > 0.05
    assert max(abs(r) for r in eq.residual) < 1e-6
    assert eq.throttle_pct[0] == pytest.approx(trq.idle_pct)      # the dead motor's: irrelevant
    assert all(trq.idle_pct <= z <= 100.0 for z in eq.throttle_pct)
    assert all(trq.tilt_min_rad <= a <= trq.tilt_max_rad for a in eq.tilt_rad)
    # the plant's own derivative on the orbit: the body rates constant, the velocity turning
    # about the vertical at the spin rate (the centre of mass on its circle), no mean fall
    x = se.initial_state(trq, eq)
    motors = [min(max(z, trq.idle_pct), 100.0) * f for z, f in zip(eq.throttle_pct, MOTOR1_LOST)]
    wrench = body_wrench(motors, list(eq.tilt_rad), trq)
    dx = derivative(x, wrench, (0.0, 0.0, 0.0), trq.mass_kg, trq.inertia_kg_m2,
                    trq.gravity_m_s2, 0.0)
    assert np.abs(dx[10:13]).max() < 1e-6                        # omega-dot, rad/s^2
    rot = np.array(quat_to_dcm(*x[6:10]))
    omega_ned = rot @ np.asarray(x[10:13])
    assert omega_ned[0:2] == pytest.approx([0.0, 0.0], abs=1e-9)  # the axis is the vertical
    assert np.asarray(dx[3:6]) == pytest.approx(np.cross(omega_ned, x[3:6]), abs=1e-6)


def test_the_plant_stays_on_the_orbit(sim, spin20):
    run = se.simulate(sim, spin20, 1.0)
    assert not run.crashed
    assert run.rates_error_rad_s < 1e-5 and run.axis_lean_deg_max < 1e-3
    assert run.drift_m < 1e-3


def test_motor1_lost_has_no_static_trim_and_a_slowest_spin(trq):
    assert not envelope.analyse(trq, MOTOR1_LOST, 0.0, 0.0)["feasible"]
    # not spinning, not even a steady descent: motor 2's idle thrust rolls the body about the
    # diagonal of motors 3 and 4, which nothing else can (the record's proof)
    static = se.solve(trq, MOTOR1_LOST, spin_rad_s=0.0)
    assert not static.feasible and static.descent_m_s == 0.0 and static.margin < -0.1
    slow = se.slowest_spin_rad_s(trq, MOTOR1_LOST)
    assert slow is not None and 10.0 < slow < 20.0
    below = se.solve(trq, MOTOR1_LOST, spin_rad_s=0.8 * slow, descend=False)
    assert not below.feasible and below.margin < 0.0


def test_half_a_motor_still_trims_static_and_spinning(trq):
    assert envelope.analyse(trq, [0.5, 1.0, 1.0, 1.0], 0.0, 0.0)["feasible"]
    eq = se.solve(trq, [0.5, 1.0, 1.0, 1.0], spin_rad_s=0.0)
    assert eq.feasible and eq.orbit_radius_m == 0.0 and max(abs(r) for r in eq.residual) < 1e-6


@pytest.mark.parametrize("factors", [[0.0, 1.0, 0.0, 1.0], [0.0, 0.0, 1.0, 1.0]],
                         ids=["adjacent", "opposite"])
def test_two_motors_lost_only_descend(trq, factors):
    """Two live rotors give at most 2 x thrust(100 %) < weight: no hover of any kind; the slowest
    steady descent needs the drag to make up the rest."""
    weight = trq.mass_kg * trq.gravity_m_s2
    assert se.max_axis_thrust_N(trq, factors) < weight
    eq = se.solve(trq, factors, spin_rad_s=30.0)
    assert not eq.feasible
    bound = math.sqrt((weight - se.max_axis_thrust_N(trq, factors)) / trq.drag_N_s2_m2)
    assert eq.descent_m_s >= bound - 1e-3
    assert eq.descent_m_s < bound + 1.0
    assert max(abs(r) for r in eq.residual) < 1e-5


def test_two_adjacent_lost_have_no_static_equilibrium(trq):
    """Both live rotors behind the centre of mass: a pitch torque only a spin can balance."""
    with pytest.raises(RuntimeError, match="no solution"):
        se.solve(trq, [0.0, 1.0, 0.0, 1.0], spin_rad_s=0.0)


def test_quad_cannot_balance_yaw_with_a_motor_lost(quad):
    eq = se.solve(quad, MOTOR1_LOST, spin_rad_s=30.0, descend=False)
    assert not eq.feasible and eq.margin < -0.05


def test_wind_leans_the_axis(trq):
    eq = se.solve(trq, MOTOR1_LOST, 8.0, 90.0, spin_rad_s=20.0)
    drag = trq.drag_N_s2_m2 * 8.0 ** 2
    assert eq.feasible
    assert eq.axis_lean_deg == pytest.approx(math.degrees(math.atan2(drag, trq.mass_kg
                                                                     * trq.gravity_m_s2)), abs=1e-3)


def test_command_writes_json(tmp_path):
    out = tmp_path / "spin.json"
    rc = envelope.main(["--spin", "--motor", "1", "--eff", "0", "--spin-rate", "20",
                        "--json", str(out)])
    assert rc == 0
    data = json.loads(out.read_text())
    assert data["equilibrium"]["feasible"] and data["equilibrium"]["spin_rad_s"] == 20.0
    assert data["control_margins"]["+Mz"] > 0 and data["control_margins"]["-Mz"] > 0
    assert envelope.main(["--spin", "--motor", "1", "--motor", "3", "--eff", "0",
                          "--spin-rate", "20"]) == 1
    assert envelope.main(["--spin", "--motor", "1", "--eff", "0", "--spin-rate", "-1"]) == 2
