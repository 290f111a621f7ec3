"""Statistics of the real recording against the values documented in pcdet_memslidar/assets/blickfeld/README.md, and the
calibrated sensor preset against the recording it was fitted on."""
import pytest

from pcdet_memslidar.sim.recording_stats import calibrate_sensor, measure, pulse_arrays, recording_stats, replay
from pcdet_memslidar.sim.sensor import get_sensor

README_ENVELOPE = {0.0: (-14.2, 14.8), 20.0: (-10.3, 13.1), 30.0: (-6.3, 10.6), 35.0: (-3.8, 8.7)}


@pytest.fixture(scope="module")
def arrays(real_bfpc):
    return pulse_arrays(real_bfpc)


def test_measured_values_match_the_readme(real_bfpc):
    stats = recording_stats(real_bfpc)
    assert stats["pulses_per_frame"] == 12312
    assert stats["frame_period_s"] == pytest.approx(0.122, abs=5e-4)
    for azimuth, (low, high) in README_ENVELOPE.items():
        assert stats["envelope"][azimuth] == pytest.approx((low, high), abs=0.1)
    assert 0.0065 <= stats["noise_sigma_median_m"] <= 0.0086
    assert all(0.006 <= sigma <= 0.0095 for sigma in stats["noise_sigma_by_range"].values())
    assert 0.01 <= stats["noise_sigma_p90_m"] <= 0.06
    assert stats["no_return_fraction"] == pytest.approx(0.054, abs=0.001)
    assert stats["never_return_fraction"] == pytest.approx(0.031, abs=0.001)
    assert (stats["intensity_min"], stats["intensity_max"]) == (3.0, 511.0)
    assert stats["intensity_median"] == pytest.approx(150, abs=5)
    assert stats["intensity_loglog_slope"] == pytest.approx(-0.2, abs=0.1)
    assert stats["range_min_m"] == pytest.approx(1.34, abs=0.01)
    assert stats["range_median_m"] == pytest.approx(5.8, abs=0.05)
    assert stats["range_max_m"] == pytest.approx(36.8, abs=0.1)


def test_calibrated_preset_is_what_the_recording_gives(arrays):
    sensor = get_sensor("calibrated")
    fitted = calibrate_sensor(arrays, intensity_scale=sensor.intensity_scale)
    for name in ("range_sigma_m", "range_sigma_per_m", "intensity_range_slope", "intensity_jitter",
                 "power_threshold", "power_softness"):
        assert fitted[name] == pytest.approx(getattr(sensor, name), rel=0.05), name
    assert fitted["min_range_m"] == sensor.min_range_m
    assert fitted["base_dropout"] == pytest.approx(sensor.base_dropout, abs=5e-4)


def test_replaying_the_scene_reproduces_the_recording(arrays):
    real = measure(**arrays)
    simulated = measure(**replay(arrays, get_sensor("calibrated"), seed=0))
    assert simulated["noise_sigma_median_m"] == pytest.approx(real["noise_sigma_median_m"], abs=0.001)
    assert simulated["no_return_fraction"] == pytest.approx(real["no_return_fraction"], abs=0.005)
    assert simulated["never_return_fraction"] == pytest.approx(real["never_return_fraction"], abs=0.005)
    assert simulated["intensity_median"] == pytest.approx(real["intensity_median"], abs=10)
    # the edge tail (mixed pixels), fitted through mixed_pixel_gap_m: 4.46 cm real
    assert simulated["noise_sigma_p90_m"] == pytest.approx(real["noise_sigma_p90_m"], rel=0.1)
    carla = measure(**replay(arrays, get_sensor("carla"), seed=0))
    assert carla["no_return_fraction"] == pytest.approx(0.031 + 0.05 * 0.969, abs=0.005)
    assert carla["noise_sigma_median_m"] > 0.02  # 0.5 % of about 6 m
