"""The bird's-eye plot of one frame of `memslidar detect`: zones, tracked boxes and their trails, no points."""
from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Polygon

from pcdet_memslidar.evaluation.figures import draw_boxes_bev, save_figure

ZONE_COLORS = {"warning": "tab:orange", "protective": "tab:red"}


def plot_tracks_frame(path: str | Path, boxes: np.ndarray, track_ids: list[int | None], trails: dict[int, np.ndarray],
                      zones: list[tuple[str, str, np.ndarray]], events: list[dict], title: str,
                      window: tuple[np.ndarray, np.ndarray]) -> Path:
    """Bird's-eye view of one frame of `memslidar detect`: zones (name, level, polygon (K, 2)) filled by level,
    detections (M, 7) coloured by track id (grey: tentative) with their trails {id: (T, 2) centres}; the frame's
    events in the title. window: the x and y ranges (2,) [m]. No points: only what detect keeps."""
    figure = Figure(figsize=(7, 7), layout="constrained")
    ax = figure.add_subplot(1, 1, 1)
    for name, level, polygon in zones:
        ax.add_patch(Polygon(polygon, closed=True, facecolor=ZONE_COLORS[level], alpha=0.2,
                             edgecolor=ZONE_COLORS[level]))
        ax.text(*polygon.mean(axis=0), f"{name} ({level})", fontsize=8, ha="center", color=ZONE_COLORS[level])
    palette = ["C0", "C2", "C4", "C5", "C6", "C8", "C9"]  # no orange, red or grey: the zones and tentative boxes
    for track_id, trail in trails.items():
        ax.plot(trail[:, 0], trail[:, 1], color=palette[track_id % len(palette)], linewidth=1, alpha=0.6)
    for box, track_id in zip(np.asarray(boxes, dtype=np.float64).reshape(-1, 7), track_ids):
        color = "0.6" if track_id is None else palette[track_id % len(palette)]
        draw_boxes_bev(ax, box[None], color, linewidth=1.5)
        if track_id is not None:
            ax.text(box[0], box[1] + 0.6, str(track_id), color=color, fontsize=9, ha="center")
    happened = "; ".join(f"{e['event']} {e['zone']} #{e['track_id']}" for e in events)
    ax.set(xlabel="x (forward) [m]", ylabel="y (left) [m]", aspect="equal", xlim=window[0], ylim=window[1],
           title=title + (f"\n{happened}" if happened else ""))
    ax.title.set_fontsize(9)
    ax.grid(alpha=0.3)
    return save_figure(figure, path)
