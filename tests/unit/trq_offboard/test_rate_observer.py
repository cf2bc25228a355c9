"""The published rates' low-pass (rates_lowpass_hz): read from the controller file, set by the
runners from the vehicle's sensing profile, refused out of the observer's reach, and flown by
the body-rate observer that carries it (trq_offboard/rate_observer.py)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from conftest import ROOT
from trq_lab.scenario import rates_lowpass_hz
from trq_offboard.config import ConfigError, load_controller, with_rates_lowpass
from trq_offboard.daemon import main as offboard_main
from trq_offboard.rate_observer import RateObserver

CTRL = ROOT / "params" / "controller"


def test_the_shipped_controllers_model_px4s_rate_filter():
    cfg = load_controller(CTRL / "trq_nmpc_eso.yaml")
    assert cfg.rates_lowpass_hz == 40.0          # PX4's IMU_GYRO_CUTOFF as shipped


@pytest.mark.parametrize("sensing, want", [("truth", 0.0), ("mocap", 40.0), ("gnss", 40.0)])
def test_the_runners_take_it_from_the_sensing_profile(sensing, want):
    assert rates_lowpass_hz(sensing) == want


def test_a_filter_the_observer_cannot_integrate_is_refused():
    cfg = load_controller(CTRL / "trq_nmpc_eso.yaml")
    # 10 substeps at 100 Hz integrate up to 1000 rad/s: about 159 Hz
    assert with_rates_lowpass(cfg, 150.0, "here").rates_lowpass_hz == 150.0
    with pytest.raises(ConfigError, match=r"here: key 'rates_lowpass_hz': got 200\.0, expected "
                                          r"at most .*159\.2 Hz"):
        with_rates_lowpass(cfg, 200.0, "here")
    with pytest.raises(ConfigError, match=r"--x: key 'rates_lowpass_hz': got -1\.0"):
        with_rates_lowpass(cfg, -1.0, "--x")


def test_the_daemon_refuses_a_bad_cutoff_with_a_clear_error(capsys):
    code = offboard_main(["--controller", str(CTRL / "trq_nmpc_eso.yaml"), "--no-log",
                          "--rates-lowpass-hz", "-3"])
    assert code == 2
    assert "rates_lowpass_hz" in capsys.readouterr().err


def test_the_controller_hands_the_rate_observers_disturbance_to_the_model():
    """With a filter the angular part of d is the rate observer's; without one, the ESO's
    (the same controller otherwise)."""
    from trq_offboard.controller import Controller
    from trq_offboard.records import StateEstimate

    cfg = load_controller(CTRL / "trq_nmpc_eso.yaml")
    raw = Controller(dataclasses.replace(cfg, rates_lowpass_hz=0.0))
    filt = Controller(cfg)
    assert raw.rate_observer is None and isinstance(filt.rate_observer, RateObserver)
    x = np.zeros(12)
    x[2] = -1.0
    for c in (raw, filt):
        c.reset(0.0, StateEstimate.from_vector(x), None)
        x1 = x.copy()
        x1[9] = 0.05                            # a roll rate appears in the next sample
        c._observe(x1, 0.01, np.zeros(9))
    assert np.array_equal(filt._observe(x1, 0.01, None)[0][3:6], filt.rate_observer.disturbance)
    assert not np.array_equal(raw._observe(x1, 0.01, None)[0][3:6],
                              filt.rate_observer.disturbance)
