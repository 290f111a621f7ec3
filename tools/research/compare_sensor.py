"""Calibration check: a sensor preset's statistics side by side with those of a real Blickfeld recording.

    python tools/research/compare_sensor.py REAL.bfpc [--frames N] [--sensor calibrated|carla]
        [--pattern cube1_2020] [--out fig.png] [--seed 0]

Both columns are measured by the same function (recording_stats.measure, beside this script). The simulated
column lets the sensor preset look at the recording's own static scene (recording_stats.replay: per pulse the mean
measured range, an albedo from the median intensity and the edges between neighbouring pulses) for as many frames as
the recording has; pulses per frame, frame period and the FoV envelope come from the scan-pattern preset. Prints a
table and writes a figure (FoV, range noise, intensity, returns per frame).
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
import warnings
from pathlib import Path

import numpy as np

import recording_stats as rs  # beside this script
from pcdet_memslidar.errors import DataFormatError
from pcdet_memslidar.io.bfpc import read_bfpc
from pcdet_memslidar.sim.pattern import get_pattern
from pcdet_memslidar.sim.sensor import get_sensor


def compare(recording_path: Path, frames: int | None, sensor_name: str, pattern_name: str, seed: int) -> dict:
    """Per-pulse arrays and statistics of the recording ('real') and of the preset ('sim')."""
    recording = read_bfpc(recording_path)
    if frames is not None:
        recording = dataclasses.replace(recording, frames=recording.frames[:frames])
    real_arrays = rs.pulse_arrays(recording)
    sim_arrays = rs.replay(real_arrays, get_sensor(sensor_name), seed=seed)
    real, sim = rs.measure(**real_arrays), rs.measure(**sim_arrays)
    real["frame_period_s"] = rs.recording_stats(recording)["frame_period_s"]
    pattern = get_pattern(pattern_name)
    sim.update(rs.pattern_stats(pattern))
    directions, _, _ = pattern.pulses()
    return dict(real=real, sim=sim, real_arrays=real_arrays, sim_arrays=sim_arrays, pattern_directions=directions,
                frames=len(recording.frames))


def table_rows(real: dict, sim: dict) -> list[tuple[str, str, str]]:
    """(quantity, real, simulated) rows, formatted."""
    rows = [("pulses per frame", f"{real['pulses_per_frame']}", f"{sim['pulses_per_frame']}"),
            ("frame period [s]", f"{real['frame_period_s']:.4f}", f"{sim['frame_period_s']:.4f}")]
    for azimuth in real["envelope"]:
        (lo_r, hi_r), (lo_s, hi_s) = real["envelope"][azimuth], sim["envelope"][azimuth]
        rows.append((f"elevation at |az| {azimuth:g} deg", f"{lo_r:.1f} .. {hi_r:.1f}", f"{lo_s:.1f} .. {hi_s:.1f}"))
    rows += [("range noise sigma median [cm]", f"{100 * real['noise_sigma_median_m']:.2f}",
              f"{100 * sim['noise_sigma_median_m']:.2f}"),
             ("range noise sigma p90 [cm]", f"{100 * real['noise_sigma_p90_m']:.2f}",
              f"{100 * sim['noise_sigma_p90_m']:.2f}")]
    for bin_ in real["noise_sigma_by_range"]:
        rows.append((f"  sigma median at {bin_[0]}-{bin_[1]} m [cm]", f"{100 * real['noise_sigma_by_range'][bin_]:.2f}",
                     f"{100 * sim['noise_sigma_by_range'].get(bin_, float('nan')):.2f}"))
    rows += [("no-return fraction [%]", f"{100 * real['no_return_fraction']:.2f}",
              f"{100 * sim['no_return_fraction']:.2f}"),
             ("never-return fraction [%]", f"{100 * real['never_return_fraction']:.2f}",
              f"{100 * sim['never_return_fraction']:.2f}"),
             ("intensity median", f"{real['intensity_median']:.0f}", f"{sim['intensity_median']:.0f}"),
             ("intensity min .. max", f"{real['intensity_min']:.0f} .. {real['intensity_max']:.0f}",
              f"{sim['intensity_min']:.0f} .. {sim['intensity_max']:.0f}"),
             ("intensity log-log slope vs range", f"{real['intensity_loglog_slope']:.3f}",
              f"{sim['intensity_loglog_slope']:.3f}"),
             ("range min / median / max [m]", f"{real['range_min_m']:.2f} / {real['range_median_m']:.2f} / "
              f"{real['range_max_m']:.1f}", f"{sim['range_min_m']:.2f} / {sim['range_median_m']:.2f} / "
              f"{sim['range_max_m']:.1f}")]
    return rows


def format_table(rows, sensor_name: str, pattern_name: str, frames: int) -> str:
    header = ("quantity", f"real ({frames} frames)", f"sim ({sensor_name} + {pattern_name})")
    widths = [max(len(row[i]) for row in [header, *rows]) for i in range(3)]
    lines = [" | ".join(cell.ljust(width) for cell, width in zip(row, widths)) for row in [header, *rows]]
    lines.insert(1, "-+-".join("-" * width for width in widths))
    return "\n".join(lines)


def plot(result: dict, out: Path, sensor_name: str, pattern_name: str) -> None:
    """2 x 3 panels: FoV, temporal sigma, sigma vs range, intensity histogram, intensity vs range, returns/frame."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    real, sim = result["real_arrays"], result["sim_arrays"]
    labels = ("real", f"sim ({sensor_name})")
    fig, axes = plt.subplots(2, 3, figsize=(17, 9))
    ax = axes[0, 0]
    directions = result["pattern_directions"]
    ax.scatter(np.degrees(real["azimuth"][0]), np.degrees(real["elevation"][0]), s=0.3, label="real pulses")
    ax.scatter(np.degrees(np.arctan2(directions[:, 1], directions[:, 0])),
               np.degrees(np.arcsin(np.clip(directions[:, 2], -1, 1))), s=0.3, alpha=0.5, label=f"{pattern_name}")
    ax.set(title="field of view (pulse directions)", xlabel="azimuth [deg] (left +)", ylabel="elevation [deg]")
    ax.legend(markerscale=10)

    sigmas = [rs.temporal_sigma(arrays["range_m"]) for arrays in (real, sim)]
    with warnings.catch_warnings():  # pulses that never return have an all-nan column
        warnings.simplefilter("ignore", RuntimeWarning)
        mean_ranges = [np.nanmean(arrays["range_m"], axis=0) for arrays in (real, sim)]
    bins = np.logspace(-3.5, -0.5, 60)
    for sigma, label in zip(sigmas, labels):
        axes[0, 1].hist(sigma[np.isfinite(sigma)], bins=bins, histtype="step", label=label, density=True)
    axes[0, 1].set(xscale="log", title="temporal range noise per pulse", xlabel="sigma [m]", ylabel="density")
    axes[0, 1].legend()

    edges = np.array([1, 2, 3, 5, 7, 10, 15, 20, 30, 40])
    centres = np.sqrt(edges[1:] * edges[:-1])
    for sigma, mean_range, label in zip(sigmas, mean_ranges, labels):
        medians = [np.nanmedian(sigma[(mean_range >= lo) & (mean_range < hi)])
                   if np.isfinite(sigma[(mean_range >= lo) & (mean_range < hi)]).sum() >= 20 else np.nan
                   for lo, hi in zip(edges[:-1], edges[1:])]
        axes[0, 2].plot(centres, 100 * np.array(medians), "o-", label=label)
    axes[0, 2].set(xscale="log", title="median range noise vs range", xlabel="range [m]", ylabel="sigma [cm]")
    axes[0, 2].legend()

    for arrays, label in zip((real, sim), labels):
        values = arrays["intensity"][np.isfinite(arrays["intensity"])]
        axes[1, 0].hist(values, bins=np.arange(0, 520, 8), histtype="step", label=label, density=True)
    axes[1, 0].set(title="intensity distribution", xlabel="intensity", ylabel="density")
    axes[1, 0].legend()

    for arrays, label in zip((real, sim), labels):
        valid = np.isfinite(arrays["range_m"])
        r, i = arrays["range_m"][valid], arrays["intensity"][valid]
        medians = [np.median(i[(r >= lo) & (r < hi)]) if ((r >= lo) & (r < hi)).sum() >= 20 else np.nan
                   for lo, hi in zip(edges[:-1], edges[1:])]
        axes[1, 1].plot(centres, medians, "o-", label=label)
    axes[1, 1].set(xscale="log", yscale="log", title="median intensity vs range", xlabel="range [m]",
                   ylabel="intensity")
    axes[1, 1].legend()

    for arrays, label in zip((real, sim), labels):
        axes[1, 2].plot(np.isfinite(arrays["range_m"]).sum(axis=1), "o-", label=label)
    axes[1, 2].axhline(result["sim"]["pulses_per_frame"], color="gray", ls="--", label=f"{pattern_name} pulses")
    axes[1, 2].set(title="returns per frame", xlabel="frame", ylabel="points")
    axes[1, 2].legend()
    for ax in axes.flat:
        ax.grid(True, alpha=0.3)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=80)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recording", type=Path, help="a real Blickfeld .bfpc recording of a static scene")
    parser.add_argument("--frames", type=int, default=None, help="use only the first N frames (>= 8 for noise)")
    parser.add_argument("--sensor", default="calibrated", help="sensor preset (default: %(default)s)")
    parser.add_argument("--pattern", default="cube1_2020", help="scan-pattern preset (default: %(default)s)")
    parser.add_argument("--out", type=Path, default=None, help="write the figure here (PNG)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    try:
        result = compare(args.recording, args.frames, args.sensor, args.pattern, args.seed)
    except (DataFormatError, ValueError) as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    print(format_table(table_rows(result["real"], result["sim"]), args.sensor, args.pattern, result["frames"]))
    if args.out:
        plot(result, args.out, args.sensor, args.pattern)
        print(f"figure: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
