"""trq_lab: the experiment layer above the two daemons.

What goes in: scenario, campaign and fault files (built-in ones by name, through `trq_params`, or
a user's by path), and the two daemons (`sil_vehicle`, `trq_offboard`) as they are installed.
What comes out: flights (over the wire or in one process), their logs, metrics, reports, figures,
and the figures of the benchmarks and analyses. It never changes how either daemon flies: every
flight here is one that the daemons fly the same way on their own.

    scenario        a scenario file (`params/scenarios/`): both daemons as processes over UDP,
                    one flight per controller, metrics.json, report.md, figures (trq-scenario)
    harness         the one closed loop in one process: the vehicle's `Sitl` and the controller's
                    `OffboardFlight` joined by an in-memory link of the same MAVLink bytes
                    (trq-inprocess; the campaigns, the benchmark and the tests fly it)
    overlays        the controller overlay every flight flies (a reference over a controller file),
                    and a perturbed airframe (a campaign's plant)
    metrics         a flight's metrics from its two logs (pure functions of arrays)
    procs           the daemons as child processes: waiting until one listens, stopping one
    ptypair         a pair of pseudo-terminals joined back to back (a serial cable, for tests)
    stress          hostile and malformed traffic against both daemons (trq-stress)
    campaign/       grids and seeded samples of flights on Dask, resumable (trq-campaign): spec
                    (the campaign file and its flights), flight (one flight on a worker), store
                    (the records and flights.csv), cli (the command, Dask and the progress bar)
    reporting/      every report: fmt (the one cell formatter), scenario (a scenario's report.md
                    and figures), campaign (a campaign's report), plant_campaign (a campaign's
                    flights against its plants' faulted trim), results (the README's results
                    tables from result files, trq-results)
    analysis/       envelope (trim and margins, trq-envelope), spin_envelope (the spinning
                    equilibria of a lost motor, trq-envelope --spin), latency_bound (the best any
                    controller could fly after a fault, given its reaction time, trq-latency-bound)
    gcs/            client (a small blocking MAVLink client), inject (trq-inject-fault), monitor
                    (trq-monitor): what a ground station does, from the command line
    bench/          nmpc (trq-bench-nmpc: the solver modes on the paper's fault flight),
                    acados_anchor (acados' RTI on the same problem, trq-bench-nmpc --anchor),
                    period (the whole control period over both daemons, trq-bench-nmpc
                    --daemons), period_floor (the daemon's machinery alone, trq-bench-floor),
                    cpu_budget (real time on a fraction of a core, trq-bench-cpu-budget), sim
                    (trq-bench-sim), wire (trq-bench-wire), hover_check (trq-hover-check)
    reallogs/       real logs in: ulog (a PX4 ULog read), ekf2_params (EKF2's parameters as the
                    vehicle's filter's), replay (trq-ulog-replay), allan and calibrate
                    (trq-sensing-calibrate), output (all files written at once)
"""
