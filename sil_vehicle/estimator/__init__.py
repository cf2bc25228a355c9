"""The autopilot's state estimator: an error-state Kalman filter with EKF2's architecture (PX4
EKF2: a delayed fusion horizon and an output predictor), a pure module: no I/O, no clock, no
random numbers; time as integer microseconds.

    derivation  the filter's equations in CasADi SX: nominal propagation, error-state F and G,
                each measurement's h and H, built once into casadi.Function objects
    codegen     those functions generated as C, compiled once into a cached library, called
                through ctypes (CasADi's interpreter without a compiler)
    params      EstimatorParams: the filter's noise figures, gates, delays and time constants,
                from EKF2's parameters (PX4's defaults unless the profile's `estimator:` sets
                them), or matched to the profile's sensors (`tuning: generator`, for studies)
    predictor   the output predictor: the delayed state carried to `now` at IMU rate, with
                EKF2's complementary correction; it sums the IMU samples per filter period too
    predictor.c  its per-sample step in C (the same numbers as the Python one, bit for bit),
                 built once with the system's C compiler and cached
    lowpass     LowPass2: the published body rates' 2-pole low-pass (PX4's IMU_GYRO_CUTOFF)
    eskf        Eskf: the filter on its delayed horizon (downsampled IMU buffer, measurement
                buffers, gated Joseph-form fusion, alignment, health) and the Estimate it gives

Use (the vehicle's tick loop; nothing here reads a clock or draws a random number):

    est = Eskf(EstimatorParams.from_profile(load_sensing("mocap", 1000)))
    est.step(t_us, readings)        # every physics tick, with the sensor suite's readings
    e = est.output()                # Estimate: pose, velocity, rates, variances, health

What the telemetry takes from an Estimate (the codec's business; a sketch for the wiring):
ODOMETRY's pose from pos_ned_m and quat_wxyz, velocity from vel_ned_m_s, rates from
rates_frd_rad_s; its pose_covariance the upper triangle of pose_cov_rpy(), its
velocity_covariance from vel_cov_ned_m2_s2 and rates_var_frd_rad2_s2 (the cross terms unknown);
ESTIMATOR_STATUS's vel_ratio, pos_horiz_ratio, pos_vert_ratio and mag_ratio as they are, its
accuracies from the variances, its flags from attitude_aligned, position_valid and diverged.
"""
