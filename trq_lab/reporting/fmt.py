"""One table cell's text, for every report (the scenario's, the campaigns', trq-results'),
and the one table of a flight's metrics.

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


# (metrics.json key, header, format): a flight's metrics as every table shows them
METRIC_COLUMNS = (
    ("controller", "controller", "{}"), ("vehicle", "vehicle", "{}"),
    ("crashed", "crashed", "{}"), ("flight_s", "flight s", "{:.1f}"),
    ("rmse_pos_m", "pos RMSE m", "{:.3f}"), ("max_pos_err_m", "max pos err m", "{:.3f}"),
    ("rmse_pos_after_fault_m", "pos RMSE after fault m", "{:.3f}"),
    ("rmse_vert_after_fault_m", "of it vertical m", "{:.3f}"),
    ("max_sink_after_fault_m", "max sink after fault m", "{:.3f}"),
    ("rmse_yaw_deg", "yaw RMSE deg", "{:.2f}"), ("max_yaw_err_deg", "max yaw err deg", "{:.2f}"),
    ("est_rmse_pos_m", "estimate pos RMSE m", "{:.4f}"),
    ("est_rmse_att_deg", "estimate att RMSE deg", "{:.2f}"),
    ("recovery_s", "recovery s", "{:.2f}"), ("diagnosis_s", "diagnosis s", "{:.2f}"),
    ("solve_ms_p50", "solve p50 ms", "{:.1f}"), ("solve_ms_p99", "solve p99 ms", "{:.1f}"))


def columns(keys: tuple[str, ...], formats: dict[str, str] | None = None) -> tuple:
    """The columns of METRIC_COLUMNS named by `keys`, in that order, `formats` overriding."""
    by_key = {k: (k, h, f) for k, h, f in METRIC_COLUMNS}
    return tuple((k, by_key[k][1], (formats or {}).get(k, by_key[k][2])) for k in keys)


def table_head(cols) -> list[str]:
    """A Markdown table's header and rule for `cols` ((key, header, format) each)."""
    return ["| " + " | ".join(h for _, h, _ in cols) + " |", "|" + "---|" * len(cols)]


def table_row(row: dict, cols) -> str:
    """One Markdown table line: each column's value in `row` by `fmt`."""
    return "| " + " | ".join(fmt(row.get(k), f) for k, _, f in cols) + " |"
