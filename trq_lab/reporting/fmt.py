"""One table cell's text, for every report: the scenario's, the campaigns', trq-results'.

Standard library only (trq-results runs without the simulator or the controller installed).
"""

from __future__ import annotations

import math
import numbers


def fmt(value: object, spec: str = "{:.3f}", *, inf: str = "-") -> str:
    """`value` by `spec`; '-' when it is missing (None) or NaN, `inf` when it is infinite (a
    crashed flight's score, in the plant-campaign report); a bool or a non-number as str."""
    if value is None:
        return "-"
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return str(value)
    if math.isnan(value):
        return "-"
    if math.isinf(value):
        return inf
    return spec.format(value)
