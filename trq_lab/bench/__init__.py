"""Benchmarks: each prints what it measured, on what machine, and ratios within one run.

    nmpc           trq-bench-nmpc: the NMPC solver modes on the paper's fault flight, side by side
    acados_anchor  acados' RTI on the same OCP replaying those flights (trq-bench-nmpc --anchor
                   acados; needs acados built beside the project)
    period         the controller's whole period from outside its process, over both daemons
                   (trq-bench-nmpc --daemons), and a controller.csv's parts
    period_floor   trq-bench-floor: the daemon's machinery alone, a recorded flight replayed
    instructions   trq-bench-instructions: the period counted in instructions (valgrind's
                   callgrind) by the library that runs them; the floor's and acados' step's too
    cpu_budget     trq-bench-cpu-budget: real time with the controller held to a share of a core
    sim            trq-bench-sim: the plant and the vehicle daemon, both physics cores
    wire           trq-bench-wire: the wire's part of a period, pymavlink's path against trq_wire's
    fused          trq-bench-fused: the fused filter's step, its C core against its Python path
    decay          trq-bench-decay: a compiled step's cost after a wait, asleep or spinning
    hover_check    trq-hover-check: an open-loop hover over UDP (the plant and the links end to end)
"""
