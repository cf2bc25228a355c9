"""The NMPC test problem the solver-consistency tests share: a state off the reference, a
reference moving north at 0.3 m/s at 2 m altitude, a disturbance on every channel, and the hover
trim as the initial guess. Hand-picked numbers, so every solver sees the same NLP."""

from __future__ import annotations

import numpy as np

from trq_offboard.allocation import Allocator
from trq_offboard.model import PredictionModel


def ocp_problem(cfg):
    """(model, u_trim, x0, x_ref, d, guess) for the controller config `cfg`."""
    model = PredictionModel(cfg.vehicle)
    alloc = Allocator(cfg.vehicle)
    u_trim = alloc.command_vector(alloc.hover())
    n = cfg.horizon_steps
    x0 = np.zeros(12)
    x0[0:3] = (0.3, -0.2, -1.8)
    x0[3:6] = (0.2, 0.1, 0.0)
    x0[6:9] = (0.05, -0.03, 0.1)
    x_ref = np.zeros((n + 1, 12))
    x_ref[:, 2] = -2.0
    x_ref[:, 3] = 0.3
    x_ref[:, 0] = 0.3 * cfg.step_s * np.arange(n + 1)
    d = np.array([0.5, -0.2, 0.3, 1.0, -2.0, 0.5])
    guess = (np.tile(u_trim, (n, 1)), np.tile(x0, (n + 1, 1)))
    return model, u_trim, x0, x_ref, d, guess
