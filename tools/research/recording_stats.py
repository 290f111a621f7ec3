"""Statistics of a LiDAR recording, to calibrate the scan pattern and the sensor model against real data.

Everything works on per-pulse arrays of shape (F, P): F frames of the same P pulses (a static scene seen F
times), with nan range / intensity where a pulse got no return. `pulse_arrays` makes them from a BfpcRecording,
`replay` makes them from a SensorModel looking at the recording's own scene, and `measure` turns either into the
same dict of numbers, so a real recording and a sensor preset can be put side by side (compare_sensor.py beside it).
`fit_pattern` and `calibrate_sensor` fitted the cube1_2020 pattern (sim.pattern) and the 'calibrated' sensor preset
(sim.sensor) to the bundled recording.
"""
from __future__ import annotations

import dataclasses
import warnings

import numpy as np
from scipy.optimize import least_squares

from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.io.bfpc import BfpcRecording
from pcdet_memslidar.sim.pattern import ScanPattern
from pcdet_memslidar.sim.sensor import SensorModel

ENVELOPE_AZIMUTHS_DEG = (0.0, 10.0, 20.0, 30.0, 35.0)
MIN_RETURNS_FOR_NOISE = 8      # a pulse needs this many returns over the frames to get a temporal sigma
OUTLIER_M = 1.0                # a return this far from its pulse's median range is an outlier (range statistics)
EDGE_GAP_M = 0.05              # neighbouring pulses farther apart in range than this straddle an edge (replay)


def pulse_arrays(recording: BfpcRecording) -> dict[str, np.ndarray]:
    """Per-pulse (F, P) arrays of a recording whose frames all fire the same pulses (same point ids).

    Returns azimuth, elevation [rad], time_offset [s], range_m [m] and intensity of the strongest return (nan where
    none), scanline (P,).
    """
    frames = recording.frames
    if not frames or any(not np.array_equal(frame.point_id, frames[0].point_id) for frame in frames):
        raise DataFormatError(recording.path, "per-pulse statistics need frames that all fire the same pulses "
                                              "(one scan pattern for the whole recording): split the recording")
    shape = (len(frames), frames[0].num_pulses)
    ranges, intensity = np.full(shape, np.nan), np.full(shape, np.nan)
    for index, frame in enumerate(frames):
        first = frame.first_returns()
        ranges[index, frame.return_pulse[first]] = frame.ranges[first]
        intensity[index, frame.return_pulse[first]] = frame.points[first, 3]
    return dict(azimuth=np.stack([frame.azimuth for frame in frames]),
                elevation=np.stack([frame.elevation for frame in frames]),
                time_offset=np.stack([frame.time_offset for frame in frames]),
                range_m=ranges, intensity=intensity, scanline=frames[0].scanline)


def fov_envelope(azimuth: np.ndarray, elevation: np.ndarray, at_deg=ENVELOPE_AZIMUTHS_DEG,
                 half_width_deg: float = 0.5) -> dict[float, tuple[float, float]]:
    """Lowest and highest elevation [deg] of the pulses within half_width_deg of azimuth +-a, for each a in at_deg."""
    azimuth, elevation = np.rad2deg(np.ravel(azimuth)), np.rad2deg(np.ravel(elevation))
    envelope = {}
    for at in at_deg:
        near = np.abs(np.abs(azimuth) - at) <= half_width_deg
        envelope[float(at)] = (float(elevation[near].min()), float(elevation[near].max()))
    return envelope


def loglog_slope(range_m: np.ndarray, intensity: np.ndarray) -> float:
    """Slope of log(intensity) against log(range) (least squares over the valid returns)."""
    valid = np.isfinite(range_m) & np.isfinite(intensity) & (intensity > 0)
    return float(np.polyfit(np.log(range_m[valid]), np.log(intensity[valid]), 1)[0])


def temporal_sigma(ranges: np.ndarray) -> np.ndarray:
    """(P,) standard deviation [m] of each pulse's range over the frames (nan with too few returns)."""
    count = np.isfinite(ranges).sum(axis=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        sigma = np.nanstd(ranges, axis=0, ddof=1)
    return np.where(count >= MIN_RETURNS_FOR_NOISE, sigma, np.nan)


def measure(azimuth: np.ndarray, elevation: np.ndarray, range_m: np.ndarray, intensity: np.ndarray,
            **_ignored) -> dict:
    """Statistics of F frames of the same P pulses, all (F, P) arrays (nan range_m = no return).

    Returns a dict: pulses_per_frame; envelope {|azimuth| deg: (min, max) elevation deg}; range noise
    (noise_sigma_median_m, noise_sigma_p90_m, noise_sigma_by_range {(lo, hi) m: median sigma}); no_return_fraction
    (per frame, averaged), never_return_fraction; intensity_median, intensity_min, intensity_max,
    intensity_loglog_slope; outlier_return_fraction (returns of pulses that return in fewer than half the frames
    or lie more than OUTLIER_M from their pulse's median range, e.g. spurious far echoes) and range_min_m,
    range_median_m, range_max_m of the other returns.
    """
    returned = np.isfinite(range_m)
    sigma = temporal_sigma(range_m)
    mean_range = _mean_over_frames(range_m)
    by_range = {}
    for low, high in ((1, 2), (2, 5), (5, 10), (10, 20), (20, 40)):
        inside = np.isfinite(sigma) & (mean_range >= low) & (mean_range < high)
        if inside.sum() >= 20:
            by_range[(low, high)] = float(np.median(sigma[inside]))
    valid_sigma = sigma[np.isfinite(sigma)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        steady = returned.sum(axis=0) >= returned.shape[0] / 2.0
        consistent = returned & steady & (np.abs(range_m - np.nanmedian(range_m, axis=0)) <= OUTLIER_M)
    values = range_m[consistent]
    return dict(
        pulses_per_frame=int(range_m.shape[1]),
        envelope=fov_envelope(azimuth[0], elevation[0]),
        noise_sigma_median_m=float(np.median(valid_sigma)), noise_sigma_p90_m=float(np.percentile(valid_sigma, 90)),
        noise_sigma_by_range=by_range,
        no_return_fraction=float(1.0 - returned.mean()), never_return_fraction=float((~returned.any(axis=0)).mean()),
        intensity_median=float(np.median(intensity[returned])), intensity_min=float(np.min(intensity[returned])),
        intensity_max=float(np.max(intensity[returned])), intensity_loglog_slope=loglog_slope(range_m, intensity),
        outlier_return_fraction=float(1.0 - consistent.sum() / returned.sum()),
        range_min_m=float(values.min()), range_median_m=float(np.median(values)), range_max_m=float(values.max()))


def _mean_over_frames(values: np.ndarray) -> np.ndarray:
    """(P,) mean over the frames where finite (nan where never finite)."""
    count = np.isfinite(values).sum(axis=0)
    return np.where(count > 0, np.nansum(values, axis=0) / np.maximum(count, 1), np.nan)


def recording_stats(recording: BfpcRecording) -> dict:
    """`measure` of a recording, plus its frame period [s] (median start-time difference)."""
    stats = measure(**pulse_arrays(recording))
    starts = np.array([frame.start_time_ns for frame in recording.frames], dtype=np.float64) * 1e-9
    ids = np.array([frame.frame_id for frame in recording.frames], dtype=np.float64)
    stats["frame_period_s"] = float(np.median(np.diff(starts) / np.diff(ids))) if len(starts) > 1 else float("nan")
    return stats


def pattern_stats(pattern: ScanPattern) -> dict:
    """Pulses per frame, frame period [s] and FoV envelope of a scan pattern, keyed like `measure`."""
    directions, _, _ = pattern.pulses()
    azimuth = np.arctan2(directions[:, 1], directions[:, 0])
    elevation = np.arcsin(np.clip(directions[:, 2], -1.0, 1.0))
    return dict(pulses_per_frame=int(directions.shape[0]), frame_period_s=pattern.frame_period_s,
                envelope=fov_envelope(azimuth, elevation))


def fit_pattern(recording: BfpcRecording, pattern: ScanPattern, frame: int = 0) -> tuple[ScanPattern, dict]:
    """Fit the mirror geometry of `pattern` to the pulse directions and times of one frame of a recording.

    Fitted: horizontal_swing_deg, keystone_per_rad, ramp_lead_lines, mirror_frequency_hz (lines, FoV and spacing
    are taken from `pattern`). Returns the fitted pattern and {rms_azimuth_deg, rms_elevation_deg}.
    """
    data = recording.frames[frame]
    time, azimuth, elevation = data.time_offset, data.azimuth, data.elevation

    def candidate(params):
        swing, keystone, lead, frequency, _ = params
        return dataclasses.replace(pattern, horizontal_swing_deg=float(swing), keystone_per_rad=float(keystone),
                                   ramp_lead_lines=float(lead), mirror_frequency_hz=float(frequency))

    def residuals(params):
        # params[-1]: mirror time of the frame's first pulse [ms], a nuisance parameter
        model_azimuth, model_elevation = candidate(params).beam_angles(time + params[-1] * 1e-3)
        return np.concatenate([model_azimuth - azimuth, model_elevation - elevation])

    first_pulse_ms = np.arccos(min(pattern.hfov_deg / pattern.horizontal_swing_deg, 1.0)) \
        / (2e-3 * np.pi * pattern.mirror_frequency_hz)
    start = [pattern.horizontal_swing_deg, pattern.keystone_per_rad, pattern.ramp_lead_lines,
             pattern.mirror_frequency_hz, first_pulse_ms]
    fit = least_squares(residuals, start, x_scale=[1.0, 0.1, 0.1, 1.0, 0.01])
    error = np.rad2deg(fit.fun.reshape(2, -1))
    return candidate(fit.x), dict(rms_azimuth_deg=float(np.sqrt(np.mean(error[0] ** 2))),
                                  rms_elevation_deg=float(np.sqrt(np.mean(error[1] ** 2))))


def replay(arrays: dict[str, np.ndarray], sensor: SensorModel, seed: int = 0) -> dict[str, np.ndarray]:
    """Let `sensor` look F times at the static scene of a recording's per-pulse arrays (from `pulse_arrays`).

    The true scene per pulse: range = mean measured range (no hit where the pulse never returned), reflectivity x
    |cos incidence| from the median intensity inverted through the sensor's own intensity law (clipped to
    [0.01, 1]), and a second surface (edge_range) where a neighbouring pulse of the same scan line lies more than
    EDGE_GAP_M away in range. Returns (F, P) arrays keyed like pulse_arrays.
    """
    frames = arrays["range_m"].shape[0]
    true_range = _mean_over_frames(arrays["range_m"])
    true_range = np.where(np.isfinite(true_range), true_range, np.inf)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        median_intensity = np.nanmedian(arrays["intensity"], axis=0)
    unit = sensor.intensity(np.where(np.isfinite(true_range), true_range, 1.0), np.ones_like(true_range),
                            np.ones_like(true_range), np.zeros_like(true_range))
    albedo = np.clip(np.nan_to_num(median_intensity, nan=1.0) / np.maximum(unit, 1.0), 0.01, 1.0)
    edge_range = _edge_ranges(true_range, arrays["scanline"])
    rng = np.random.default_rng(seed)
    ranges, intensity = np.full(arrays["range_m"].shape, np.nan), np.full(arrays["range_m"].shape, np.nan)
    for index in range(frames):
        measured, value, valid = sensor.measure(true_range, np.ones_like(albedo), albedo, rng, edge_range)
        ranges[index] = np.where(valid, measured, np.nan)
        intensity[index] = np.where(valid, value, np.nan)
    return dict(arrays, range_m=ranges, intensity=intensity)


def _edge_ranges(true_range: np.ndarray, scanline: np.ndarray) -> np.ndarray:
    """(P,) range of the neighbour along the scan line that differs most, where it differs by > EDGE_GAP_M."""
    same_line = scanline[1:] == scanline[:-1]
    before, after = np.full(true_range.shape, np.nan), np.full(true_range.shape, np.nan)
    before[1:] = np.where(same_line, true_range[:-1], np.nan)
    after[:-1] = np.where(same_line, true_range[1:], np.nan)
    with np.errstate(invalid="ignore"):
        gap_before = np.nan_to_num(np.abs(before - true_range), nan=-1.0)
        gap_after = np.nan_to_num(np.abs(after - true_range), nan=-1.0)
    neighbour = np.where(gap_before >= gap_after, before, after)
    return np.where(np.maximum(gap_before, gap_after) > EDGE_GAP_M, neighbour, np.nan)


def calibrate_sensor(arrays: dict[str, np.ndarray], intensity_scale: float, range_exponent: float = 2.0) -> dict:
    """Fit the SensorModel numbers that a static recording determines, from its per-pulse (F, P) arrays.

    Returns a dict of SensorModel fields: range_sigma_m and range_sigma_per_m (line through the median temporal
    sigma of 1-20 m range bins), intensity_range_slope (log-log slope), intensity_jitter (median per-pulse
    standard deviation of log intensity over the frames), min_range_m (shortest return, floored to 0.1 m) and
    base_dropout, power_threshold, power_softness (maximum-likelihood fit of how often each pulse that returned at
    least once misses, against its received power reflectivity x |cos| / range^range_exponent, the reflectivity
    x |cos| inverted from the median intensity with intensity_scale, which the recording alone cannot fix).
    """
    ranges, intensity = arrays["range_m"], arrays["intensity"]
    returned = np.isfinite(ranges)
    sigma, mean_range = temporal_sigma(ranges), _mean_over_frames(ranges)
    centres, medians, counts = [], [], []
    for low, high in ((1, 2), (2, 5), (5, 10), (10, 20)):
        inside = np.isfinite(sigma) & (mean_range >= low) & (mean_range < high)
        if inside.sum() >= 20:
            centres.append(np.median(mean_range[inside]))
            medians.append(np.median(sigma[inside]))
            counts.append(inside.sum())
    sigma_per_m, sigma_0 = np.polyfit(centres, medians, 1, w=np.sqrt(counts))
    slope = loglog_slope(ranges, intensity)

    with np.errstate(divide="ignore", invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        log_intensity = np.log(np.where(intensity > 0, intensity, np.nan))
        jitter = np.nanstd(log_intensity, axis=0, ddof=1)[returned.sum(axis=0) >= MIN_RETURNS_FOR_NOISE]
        median_intensity = np.nanmedian(intensity, axis=0)

    # detection: every pulse that returned at least once is a hit; count its misses over the frames
    hits = returned.sum(axis=0)
    ever = hits > 0
    albedo = median_intensity[ever] / (intensity_scale * (mean_range[ever] / 5.0) ** slope)
    log_power = np.log(np.maximum(albedo, 1e-6)) - range_exponent * np.log(mean_range[ever])
    frames = ranges.shape[0]

    def negative_log_likelihood(params):
        base, log_threshold, softness = params
        detect = (1.0 - base) / (1.0 + np.exp(-(log_power - log_threshold) / softness))
        detect = np.clip(detect, 1e-9, 1.0 - 1e-9)
        return -np.sum(hits[ever] * np.log(detect) + (frames - hits[ever]) * np.log(1.0 - detect))

    fit = least_squares(lambda p: np.sqrt(2.0 * negative_log_likelihood(p)), [0.001, np.median(log_power) - 4.0, 0.5],
                        bounds=([0.0, -30.0, 0.05], [0.2, 0.0, 5.0]))
    base, log_threshold, softness = fit.x
    return dict(range_sigma_m=float(sigma_0), range_sigma_per_m=float(sigma_per_m),
                intensity_range_slope=float(slope), intensity_jitter=float(np.median(jitter)),
                min_range_m=float(np.floor(np.nanmin(ranges) * 10.0) / 10.0),
                base_dropout=float(base), power_threshold=float(np.exp(log_threshold)), power_softness=float(softness))
