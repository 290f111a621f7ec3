"""The Cube 1 scan pattern model against its definition (against the real recording:
tests/tools/test_recording_stats.py)."""
import dataclasses

import numpy as np
import pytest

from pcdet_memslidar.errors import ConfigError
from pcdet_memslidar.sim.pattern import get_pattern


def test_paper_pattern_size_and_timing():
    pattern = get_pattern("cube1_paper")
    directions, time_offset, line = pattern.pulses()
    assert directions.shape == (36000, 3)  # 200 lines x 180 pulses (72 deg / 0.4 deg)
    assert pattern.frame_period_s == pytest.approx(0.4)
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0, atol=1e-12)
    assert time_offset[0] == 0.0 and (np.diff(time_offset) > 0).all() and time_offset[-1] < 0.4
    assert np.array_equal(np.unique(line), np.arange(200))
    azimuth = np.rad2deg(np.arctan2(directions[:, 1], directions[:, 0]))
    assert np.abs(azimuth).max() == pytest.approx(35.8, abs=1e-4)  # clipped straight at +-hFoV/2
    elevation = np.rad2deg(np.arcsin(directions[:, 2]))
    assert elevation.max() < 15.5 and elevation.min() > -15.5 and elevation.max() > 14.5


def test_frame_modes_and_interleave():
    pattern = get_pattern("cube1_2020")
    up = dataclasses.replace(pattern, frame_mode="up").pulses()
    down = dataclasses.replace(pattern, frame_mode="down").pulses()
    assert up[0].shape[0] == down[0].shape[0] == 18 * 342
    assert up[0][:, 2].max() > 0.25 and np.abs(down[0][-342:, 2]).max() < 0.01  # down ramp ends flat
    interleaved, _, line = dataclasses.replace(pattern, pulse_type="interleave").pulses()
    azimuth = np.rad2deg(np.arctan2(interleaved[:, 1], interleaved[:, 0]))
    even, odd = np.sort(azimuth[line == 0]), np.sort(azimuth[line == 1])
    assert np.median(even[:341] - odd[:341]) == pytest.approx(0.105, abs=1e-6)  # shifted by +-spacing/4


def test_bad_settings_raise_config_errors():
    with pytest.raises(ConfigError, match="frame_mode"):
        dataclasses.replace(get_pattern("cube1_paper"), frame_mode="sideways")
    with pytest.raises(ConfigError, match="hfov_deg"):
        dataclasses.replace(get_pattern("cube1_paper"), hfov_deg=90.0)
    with pytest.raises(ConfigError, match="unknown scan pattern 'cube2'"):
        get_pattern("cube2")
