"""Shared fixtures of the test suite: paths to the parameter files (from this file, never from the
working directory), loaded parameter records, and a free UDP port finder."""

from __future__ import annotations

import socket
import sys
from pathlib import Path

import pytest

import trq_params

ROOT = Path(__file__).resolve().parent.parent
PARAMS = trq_params.DIR
SIM_DEFAULT = PARAMS / "sim" / "default.yaml"
TRQ_YAML = PARAMS / "vehicle" / "trq.yaml"
QUAD_YAML = PARAMS / "vehicle" / "quad.yaml"


def cli(command: str) -> list[str]:
    """The argv prefix of an installed console script (trq-scenario, ...): the one beside this
    interpreter, as a user of this environment runs it."""
    path = Path(sys.executable).parent / command
    assert path.is_file(), f"{command} is not installed beside {sys.executable}: pip install -e ."
    return [str(path)]


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that nobody was bound to a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def free_port():
    """Call it to get a fresh free UDP port on 127.0.0.1."""
    return free_udp_port


@pytest.fixture(scope="session")
def root() -> Path:
    return ROOT


@pytest.fixture(scope="session")
def sim_default_path() -> Path:
    return SIM_DEFAULT


@pytest.fixture(scope="session")
def trq_path() -> Path:
    return TRQ_YAML


@pytest.fixture(scope="session")
def quad_path() -> Path:
    return QUAD_YAML


@pytest.fixture(scope="session")
def sim():
    """The default simulation settings (trq, lockstep, 1 kHz physics); frozen, so shared."""
    from sil_vehicle.config import load_sim
    return load_sim(SIM_DEFAULT)


@pytest.fixture(scope="session")
def trq():
    from sil_vehicle.config import load_vehicle
    return load_vehicle(TRQ_YAML)


@pytest.fixture(scope="session")
def quad():
    from sil_vehicle.config import load_vehicle
    return load_vehicle(QUAD_YAML)
