"""tools/research/recording_stats.py: statistics of the real recording against the values documented in
pcdet_memslidar/assets/blickfeld/README.md, the calibration against a hand-made recording of a known sensor, the
calibrated preset replaying the real scene, and the Cube 1 scan pattern preset against the real recording."""
import dataclasses

import numpy as np
import pytest

from pcdet_memslidar.sim.pattern import get_pattern
from pcdet_memslidar.sim.sensor import get_sensor

README_ENVELOPE = {0.0: (-14.2, 14.8), 20.0: (-10.3, 13.1), 30.0: (-6.3, 10.6), 35.0: (-3.8, 8.7)}


@pytest.fixture(scope="module")
def rs(load_tool):
    return load_tool("research/recording_stats.py")


@pytest.fixture(scope="module")
def arrays(rs, real_bfpc):
    return rs.pulse_arrays(real_bfpc)


@pytest.fixture(scope="module")
def real_stats(rs, real_bfpc):
    return rs.recording_stats(real_bfpc)


def test_measured_values_match_the_readme(real_stats):
    assert real_stats["pulses_per_frame"] == 12312
    assert real_stats["frame_period_s"] == pytest.approx(0.122, abs=5e-4)
    for azimuth, (low, high) in README_ENVELOPE.items():
        assert real_stats["envelope"][azimuth] == pytest.approx((low, high), abs=0.1)
    assert 0.0065 <= real_stats["noise_sigma_median_m"] <= 0.0086
    assert all(0.006 <= sigma <= 0.0095 for sigma in real_stats["noise_sigma_by_range"].values())
    assert 0.01 <= real_stats["noise_sigma_p90_m"] <= 0.06
    assert real_stats["no_return_fraction"] == pytest.approx(0.054, abs=0.001)
    assert real_stats["never_return_fraction"] == pytest.approx(0.031, abs=0.001)
    assert (real_stats["intensity_min"], real_stats["intensity_max"]) == (3.0, 511.0)
    assert real_stats["intensity_median"] == pytest.approx(150, abs=5)
    assert real_stats["intensity_loglog_slope"] == pytest.approx(-0.2, abs=0.1)
    assert real_stats["range_min_m"] == pytest.approx(1.34, abs=0.01)
    assert real_stats["range_median_m"] == pytest.approx(5.8, abs=0.05)
    assert real_stats["range_max_m"] == pytest.approx(36.8, abs=0.1)


HAND_MADE = dict(range_sigma_m=0.004, range_sigma_per_m=0.0006, intensity_range_slope=-0.6, intensity_jitter=0.08,
                 intensity_scale=200.0, albedo=0.5, power_threshold=1e-4, power_softness=0.2)


def hand_made_recording() -> dict:
    """(100, 90) range_m and intensity arrays of a static scene seen by a known sensor (HAND_MADE), built so that each
    fitted number has an exact answer:
    - 4 x 20 always-returning pulses at mean ranges 1.25, 3, 7 and 15 m, each range alternating r e^+-delta over the
      frames: sample standard deviation (ddof 1) range_sigma_m + range_sigma_per_m x mean range;
    - their intensity on the law intensity_scale x albedo x (range / 5 m)^intensity_range_slope of the measured range,
      times e^+-j in a pattern orthogonal to the range's: the log-log line exact, and every pulse's standard deviation
      of log intensity intensity_jitter (j from jitter and the range's share of it);
    - 9 pulses at constant ranges (57-88 m, outside the noise bins) that return in the first 10, 20, ..., 90 of 100
      frames, at the received power where the logistic detection curve of power_threshold and power_softness (no
      base dropout) gives exactly that fraction: the maximum-likelihood fit is the truth;
    - one pulse that never returns (left out of everything)."""
    sensor, frames = HAND_MADE, 100
    scale = sensor["intensity_scale"] * sensor["albedo"]  # intensity of a return at 5 m
    frame = np.arange(frames)
    range_sign, intensity_sign = np.where(frame % 2 == 0, 1.0, -1.0), np.where(frame % 4 < 2, 1.0, -1.0)
    stretch = np.sqrt(frames / (frames - 1))  # sample standard deviation of +-1 over the frames
    ranges, intensity = [], []
    for mean_range in (1.25, 3.0, 7.0, 15.0):
        sigma = sensor["range_sigma_m"] + sensor["range_sigma_per_m"] * mean_range
        delta = np.arctanh(sigma / (mean_range * stretch))  # r sinh(delta) x stretch = sigma, r cosh(delta) = mean
        measured = mean_range / np.cosh(delta) * np.exp(delta * range_sign)
        jitter = np.sqrt((sensor["intensity_jitter"] / stretch) ** 2 - (sensor["intensity_range_slope"] * delta) ** 2)
        value = scale * (measured / 5.0) ** sensor["intensity_range_slope"] * np.exp(jitter * intensity_sign)
        ranges += [measured] * 20
        intensity += [value] * 20
    for returns in range(10, 100, 10):
        fraction = returns / frames
        log_power = np.log(sensor["power_threshold"]) + sensor["power_softness"] * np.log(fraction / (1 - fraction))
        distance = np.exp((np.log(sensor["albedo"]) - log_power) / 2.0)  # power = albedo / range^2
        returned = frame < returns
        ranges.append(np.where(returned, distance, np.nan))
        intensity.append(np.where(returned, scale * (distance / 5.0) ** sensor["intensity_range_slope"], np.nan))
    ranges.append(np.full(frames, np.nan))
    intensity.append(np.full(frames, np.nan))
    return dict(range_m=np.array(ranges).T, intensity=np.array(intensity).T)


def test_calibration_recovers_the_sensor_of_a_hand_made_recording(rs):
    fitted = rs.calibrate_sensor(hand_made_recording(), intensity_scale=HAND_MADE["intensity_scale"])
    for name in ("range_sigma_m", "range_sigma_per_m", "intensity_range_slope", "intensity_jitter"):
        assert fitted[name] == pytest.approx(HAND_MADE[name], rel=1e-9), name
    assert fitted["min_range_m"] == 1.2  # the shortest return, 1.2453 m, floored to 0.1 m
    assert fitted["base_dropout"] == pytest.approx(0.0, abs=1e-9)
    # the likelihood fit stops at scipy's ftol on sqrt(2 x negative log-likelihood): to about 0.1 % here
    assert fitted["power_threshold"] == pytest.approx(HAND_MADE["power_threshold"], rel=1e-4)
    assert fitted["power_softness"] == pytest.approx(HAND_MADE["power_softness"], rel=3e-3)


def test_replaying_the_scene_reproduces_the_recording(rs, arrays):
    real = rs.measure(**arrays)
    simulated = rs.measure(**rs.replay(arrays, get_sensor("calibrated"), seed=0))
    assert simulated["noise_sigma_median_m"] == pytest.approx(real["noise_sigma_median_m"], abs=0.001)
    assert simulated["no_return_fraction"] == pytest.approx(real["no_return_fraction"], abs=0.005)
    assert simulated["never_return_fraction"] == pytest.approx(real["never_return_fraction"], abs=0.005)
    assert simulated["intensity_median"] == pytest.approx(real["intensity_median"], abs=10)
    # the edge tail (mixed pixels), fitted through mixed_pixel_gap_m: 4.46 cm real
    assert simulated["noise_sigma_p90_m"] == pytest.approx(real["noise_sigma_p90_m"], rel=0.1)
    carla = rs.measure(**rs.replay(arrays, get_sensor("carla"), seed=0))
    assert carla["no_return_fraction"] == pytest.approx(0.031 + 0.05 * 0.969, abs=0.005)
    assert carla["noise_sigma_median_m"] > 0.02  # 0.5 % of about 6 m


def test_recording_pattern_matches_real_recording(rs, real_stats):
    model = rs.pattern_stats(get_pattern("cube1_2020"))
    assert abs(model["pulses_per_frame"] - real_stats["pulses_per_frame"]) <= 0.02 * real_stats["pulses_per_frame"]
    assert model["frame_period_s"] == pytest.approx(real_stats["frame_period_s"], rel=1e-3)
    for azimuth in rs.ENVELOPE_AZIMUTHS_DEG:
        np.testing.assert_allclose(model["envelope"][azimuth], real_stats["envelope"][azimuth], atol=1.0,
                                   err_msg=f"elevation envelope at |azimuth| = {azimuth} deg")


def test_symmetric_ellipse_misses_the_real_envelope(rs, real_stats):
    symmetric = dataclasses.replace(get_pattern("cube1_2020"), keystone_per_rad=0.0)
    model = rs.pattern_stats(symmetric)["envelope"][35.0]
    assert abs(model[0] - real_stats["envelope"][35.0][0]) > 1.0  # the keystone term is what makes it fit


def test_fit_pattern_recovers_the_preset_from_a_plain_start(rs, real_bfpc):
    preset = get_pattern("cube1_2020")
    start = dataclasses.replace(preset, horizontal_swing_deg=80.0, keystone_per_rad=0.0, ramp_lead_lines=0.0,
                                mirror_frequency_hz=148.0)
    fitted, error = rs.fit_pattern(real_bfpc, start)
    assert fitted.horizontal_swing_deg == pytest.approx(preset.horizontal_swing_deg, abs=0.05)
    assert fitted.keystone_per_rad == pytest.approx(preset.keystone_per_rad, abs=0.01)
    assert fitted.ramp_lead_lines == pytest.approx(preset.ramp_lead_lines, abs=0.01)
    assert fitted.mirror_frequency_hz == pytest.approx(preset.mirror_frequency_hz, abs=0.01)
    assert error["rms_azimuth_deg"] < 0.1 and error["rms_elevation_deg"] < 0.15
