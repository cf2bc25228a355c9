"""Offboard controller of the tilt-rotor quadcopter: NMPC + extended state observer + control
allocation, flying a vehicle through MAVLink alone (it never imports sil_vehicle)."""
