"""Compatibility re-export: the CSV log and the .tlog writer live in trq_wire.logfile (shared
with the controller). Kept for tools/inprocess.py, which imports FlightLog from here; new code
imports trq_wire.logfile."""

from trq_wire.logfile import CsvLog as FlightLog
from trq_wire.logfile import Tlog
from trq_wire.logfile import read_csv_log as read_flight_log

__all__ = ["FlightLog", "Tlog", "read_flight_log"]
