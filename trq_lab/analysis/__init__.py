"""Analyses of what is physically possible, independent of any controller.

    envelope        airframe + motor fault + wind -> the hover trim and the force and torque
                    margins left to the actuators (CasADi + IPOPT on the simulator's rotor model)
    spin_envelope   airframe + motors lost + wind -> the spinning ("relaxed hover") equilibria,
                    their margins, the orbit's linearisation, the plant flown from one
                    (trq-envelope --spin)
    spin_flight     the lost-motor controller (trq_offboard/spin.py) flown in the plant in one
                    process: on the orbit, through the transition from hover, to touchdown
    latency_bound   a flight's logs + a reaction latency -> the smallest position error any
                    controller could have flown after the fault (an optimal control problem)
"""
