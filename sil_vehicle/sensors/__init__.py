"""Simulated sensors: pure, seeded models of what the vehicle's sensors would read, sampled in
lockstep with the physics. What goes in: a sensing profile (params/sensing/*.yaml), an injected
numpy Generator and, per physics tick, the plant's truth. What comes out: typed readings, each
with its time of validity (and its arrival time when delayed). They never read a clock, hold
global random state or touch the link; each model's step is a pure function of (params, state,
truth, noise samples), the suite the only thing that holds state.

    truth     the record of what the plant knows at a tick (position, velocity, attitude, rates,
              specific force, motor outputs)
    noise     continuous-time figures to per-sample noise: white, random walk, Gauss-Markov
    delay     a bounded delay line: readings held until their arrival time
    imu       gyro and accelerometer: noise density, bias random walk, turn-on bias, rotor
              vibration lines behind the chip's filter, full scales, integration per interval
    baro      pressure altitude with white noise and a Gauss-Markov drift (ISA pressure)
    mag       the earth's field in body axes, with bias and noise
    gnss      NED position and velocity, delayed, Gauss-Markov error, fix type and accuracy
    mocap     pose only, with latency, noise and dropouts
    profile   sensing profiles from YAML into the models' frozen records (load_sensing)
    suite     SensorSuite: the profile's sensors sampled at their rates, readings due per tick
    faults    SensorFaults: injected sensor failures (off, stuck, garbage, wrong) on the readings
"""
