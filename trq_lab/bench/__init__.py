"""Benchmarks: each prints what it measured, on what machine, and ratios within one run.

    nmpc         trq-bench-nmpc: the NMPC solver modes on the paper's fault flight, side by side
    acados_anchor  acados' RTI on the same OCP replaying those flights (trq-bench-nmpc --anchor
                 acados; needs acados built beside the project)
    sim          trq-bench-sim: the plant and the vehicle daemon, both physics cores
    hover_check  trq-hover-check: an open-loop hover over UDP (the plant and the links end to end)
"""
