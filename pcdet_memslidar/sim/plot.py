"""Pictures of a frame: bird's-eye view and side view of the points with the boxes drawn in."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from pcdet_memslidar.geometry.boxes import boxes_to_corners_3d
from pcdet_memslidar.utils.atomic import atomic_path


def plot_frame(points: np.ndarray, boxes: np.ndarray, path: str | Path, title: str = "",
               max_range_m: float = 35.0) -> Path:
    """Save a PNG with the bird's-eye view (x forward up the page, y left) and the side view (x, z) of
    (N, 4) points coloured by intensity and (M, 7) boxes [x, y, z_center, dx, dy, dz, heading]."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    keep = np.hypot(points[:, 0], points[:, 1]) < max_range_m
    points = points[keep]
    corners = boxes_to_corners_3d(np.asarray(boxes, dtype=np.float64).reshape(-1, 7))
    figure, (top, side) = plt.subplots(1, 2, figsize=(16, 7), gridspec_kw=dict(width_ratios=[1, 1.4]))
    top.scatter(-points[:, 1], points[:, 0], s=0.3, c=points[:, 3], cmap="viridis", linewidths=0)
    side.scatter(points[:, 0], points[:, 2], s=0.3, c=points[:, 3], cmap="viridis", linewidths=0)
    for box in corners:
        ring = box[[0, 1, 2, 3, 0]]
        top.plot(-ring[:, 1], ring[:, 0], "r-", linewidth=1.0)
        side.plot([box[:, 0].min(), box[:, 0].max(), box[:, 0].max(), box[:, 0].min(), box[:, 0].min()],
                  [box[:, 2].min(), box[:, 2].min(), box[:, 2].max(), box[:, 2].max(), box[:, 2].min()],
                  "r-", linewidth=1.0)
    top.set(xlabel="-y (right) [m]", ylabel="x (forward) [m]", title=f"bird's-eye view {title}", aspect="equal")
    side.set(xlabel="x (forward) [m]", ylabel="z (up) [m]", title="side view", aspect="equal", ylim=(-0.5, 6))
    figure.tight_layout()
    with atomic_path(path.with_suffix(".png")) as tmp:
        figure.savefig(tmp, dpi=110, format="png")
    plt.close(figure)
    return path.with_suffix(".png")
