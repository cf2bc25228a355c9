"""Fault campaigns at scale: a grid and/or a seeded random sample of flights over fault, wind,
trajectory, link, plant, sensing, sensor outage and controller, flown on Dask (a LocalCluster by
default, or an existing cluster).

    trq-campaign smoke --out out/campaign_smoke --workers 2
    trq-campaign CAMPAIGN.yaml --out DIR [--workers N | --scheduler tcp://HOST:8786]
                             [--max-flights N] [--retry-failed] [--keep-logs] [--report-only]
                             [--rescore] [--dry-run]

Each flight is the scenario runner's lockstep vehicle and controller code, flown in one process
(trq_lab.harness: `Sitl` and `OffboardFlight` joined by an in-memory link carrying the same
MAVLink bytes), and measured by trq_lab.metrics as the scenario runner measures a run.

Outputs in DIR:
    flights/<id>.json   one per flight flown (inputs, metrics, status, error traceback if any),
                        <id> a stable hash of the flight's inputs and of the parameter files it
                        reads: a rerun skips every flight that has one (failed ones too, unless
                        --retry-failed), so an interrupted campaign resumes where it stopped
    flights.csv         one row per flight of the campaign flown so far: inputs and metrics
    report.md           success rate and position RMSE per controller against fault severity
                        and wind (tables), where each controller stops coping, and the figures
    success.png, rmse.png   the heat maps
    metrics.json        the report's summary per controller (and the targets missed), which
                        trq-results turns into the README's campaigns row
    logs/<id>/          with --keep-logs, each flight's flight.csv and controller.csv: what
                        --rescore measures again when a metric is added after the flights flew
    last_run.json       the last run's counts, wall and CPU time, and the QP library the NMPCs
                        solved with (CasADi's libhpipm, or $TRQ_HPIPM_LIBRARY's: another library
                        flies the same flights with other last bits)
With a plant axis, report.md also sets every flight against its plant's faulted trim
(trq_lab.reporting.plant_campaign: envelope classes, rank correlations, paired comparison,
targets), with
margin.png, rmse_dist.png and params.png.

Campaign file (strict: an unknown or misspelt key is an error naming the file and the key):

    name: smoke
    description: ...
    seed: 1                   # flight seeds derive from it and from the flight's fault, wind,
                              # trajectory and repeat (all controllers of a cell share a seed)
    controllers: [trq_nmpc_eso, quad_nmpc]      # names in params/controller/ (or YAML paths)
    success_rmse_m: 0.1       # success: not crashed and position RMSE after the fault below this
    recovery_threshold_m: 0.1 # trq_lab.metrics's recovery time threshold
    timeout_s: 120            # simulated seconds; a flight still flying then is a 'timeout'
    repeats: 1                # optional: fly every cell with this many seeds
    grid:                     # every combination; in an axis a list of values is a dimension
      fault: {motor: [1, 2], effectiveness: [1.0, 0.5], at_s: 4.0}
      wind: {speed_m_s: [0.0, 8.0], direction_deg: 0.0}
      trajectory: {kind: hover, altitude_m: 1.0, duration_s: 2.0}
    sample:                   # n seeded random flights; a list is a choice, {uniform: [lo, hi]}
      n: 20                   # a continuous draw
      seed: 5
      fault: {motor: [1, 2, 3, 4], effectiveness: {uniform: [0.3, 1.0]}, at_s: 4.0}

An axis of `grid` may also be a list of such mappings (their union); `none` in the fault axis is
a flight without a fault. Axes left out: no fault, no wind, the controller file's reference, a
clean link, the airframe file as it is. In `sample` a number may also be {normal: [mean, sd]}
(truncated to the key's range).
An axis's keys are the dotted paths of the schema it sets (trq_params.schema.AXIS_MODELS: the
same names, types and ranges): a fault is a fault script's motor or servo event, a wind a wind
event's wind, a trajectory a controller's reference, a link the offboard link's impairment, a
plant trq_params.schema.Plant, a sensing the vehicle's sensing profile
(trq_params.schema.SensingAxis: `profile`, a built-in name or a path beside the campaign file;
written as the axis itself, `sensing: [truth, mocap]`, it is that key). Every spec carries its
`sensing` (truth by default, which stays out of the id: campaigns without the axis keep their
ids); a profile enters the id and the parameter digest, not the seed. flights.csv has a sensing
column; a campaign that varies it gets its report's tables per profile.
An outage (trq_params.schema.OutageAxis: sensor, at_s, duration_s; `none` as in the fault axis)
turns a sensor off at at_s and on again at at_s + duration_s: two sensor events that join the
flight's fault script (MAV_CMD_INJECT_FAILURE's OFF, then OK), the fault's onset staying the
fault's. A grid's outage flies under the sensing profiles that carry its sensor and not under
the others (`sensing: [mocap, rtk]` with a mocap and a gnss outage: each under its own); one
that no profile carries, or a sampled one that the draw's profile does not, is an error naming
the file and the key. `none`, or the axis left out, keeps the spec, id and flight it always
had; an outage enters the spec and the id, not the seed (a sample draws it from its own
generator: the other axes draw as without it). With the axis, flights.csv has the outage's columns (outage,
outage_sensor, outage_at_s, outage_duration_s) and max_pos_err_outage_m (trq_lab.metrics: the
largest position error from the outage's start to OUTAGE_SETTLE_S after its end), and the
report's tables are per outage when it varies.
Fault keys: at_s and either motor (1..4) with effectiveness, or time_varying.a, time_varying.b,
time_varying.w, time_varying.phi (e = a - b sin(w t + phi)), or stopped: true; or servo (1..4)
with stuck_deg. Wind keys: speed_m_s, direction_deg (from, clockwise from north), gusts,
gust_sigma_m_s. Link keys (the offboard link's seeded impairment, as a scenario's
offboard_link; the controller is told its round trip as applied_delay_s, as by the scenario
runner): loss, delay_ms, jitter_ms, duplicate, reorder. Plant keys (the SIMULATED airframe
only, each controller's own file: trq_lab.overlays.PLANT_PARAMS): mass_scale, inertia_scale,
arm_length_scale, thrust_scale, torque_scale (a curve's coefficients together), motor_lag_scale,
motor_rate_scale, servo_lag_scale, servo_rate_scale, drag_scale, idle_offset_pct; every plant is
checked against every controller's airframe when the campaign is read (a plant that cannot lift
the weight is an error naming the draw). The plant enters the flight's spec (and so its id) but
not its seed: the plants of a cell meet the same noise and gusts. `controller_model: plant` (or
[nominal, plant], both) gives the controller's model the plant's airframe too; default nominal.
`targets` (optional): {controller, min_margin_pct, rmse_after_fault_m, share, better: [{worse,
share}]}, judged in the report
(trq_lab.reporting.plant_campaign).
`flight_targets` (optional, any campaign): a list of {controller, metric, max, per, share,
sensing, outage}: among the flights of `controller` (under the profile `sensing` only, and with
an outage of the sensor `outage` only (`none`: without one), when given; a target on
max_pos_err_outage_m names the outage's sensor), at
least `share` (default 1) have `metric` (one of flights.csv's metrics,
trq_params.schema.FLIGHT_METRICS) <= `max` (times the flight's own `per`, when given), judged in
the report (trq_lab.reporting.campaign); a failed flight, or a crashed one on any metric but
`crashed`, does not meet it.
Trajectory keys: those of the controller file's `reference` (kind, altitude_m,
climb_speed_m_s, hold_s, duration_s, ramp_s, radius_m, period_s, helix_climb_m, step_ned_m, land);
their types are checked when the campaign is read, their values and combinations (ramp_s at most
half of duration_s, ...) by the controller's own loader when the flight is prepared: an invalid
one is a failed flight, recorded with the loader's message.

Exit status: 0 when every flight of the campaign has flown without an error, 1 otherwise, 2 on a
bad campaign file or command line.

The package, one module per stage:

    spec     the campaign file: its axes, checked key by key, and the flights it plans
    flight   one flight on a worker: the harness's closed loop, its metrics, its faulted trim
    store    the flights flown (DIR/flights/<id>.json) and flights.csv, one row per flight
    cli      trq-campaign: Dask (an optional dependency, imported in one place) and the progress
    (the report: trq_lab.reporting.campaign, and trq_lab.reporting.plant_campaign)
"""
