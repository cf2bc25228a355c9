"""Offboard controller of the tilt-rotor quadcopter: NMPC + extended state observer + control
allocation, flying a vehicle through MAVLink alone (it never imports sil_vehicle). What both
ends of the wire must compute identically (signing, actuator scaling, log files, the compiled-code
cache) comes from trq_wire."""
