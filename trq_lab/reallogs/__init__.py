"""Real logs in: PX4 ULogs (and the vehicle's own static IMU recordings) read, replayed through
the vehicle's filter and turned into sensing profiles. The contract: docs/logs.md.

    ulog          read_ulog(path) -> UlogData: a log's sensors, its EKF2's outputs and EKF2_*
                  parameters as arrays, old and new topic layouts; LogError names file and topic
    ekf2_params   a log's EKF2 parameters (PX4's defaults where it is silent) as the schema's
                  Ekf2 record, through EstimatorParams.ekf2 for the sensors the log has
    replay        trq-ulog-replay: the log's sensors through sil_vehicle's Eskf, compared with
                  the log's EKF2 (report.md, metrics.json, plots)
    allan         Allan deviation (allantools) of an IMU at rest: noise densities, bias
                  instability, random walks; the vehicle's IMU model run at rest, vectorised
    calibrate     trq-sensing-calibrate: a sensing profile (params/sensing format, `extends:` a
                  built-in) from a log or a static recording; in-flight vibration spectra and
                  the rotor lines they track
    output        every output written at once at the end (nothing half-written on an error)

It imports sil_vehicle (the filter, the sensor models) and never the offboard side.
"""
