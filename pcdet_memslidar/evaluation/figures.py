"""Figures (PNG, matplotlib without pyplot): one frame with its boxes; for the reproduction Fig. 3-style example
frames, precision-recall curves of M1-M4, AP against inference time, training curves; AP along a sweep; a frame of
`memslidar detect` with zones and tracks.

Boxes are OpenPCDet LiDAR boxes (M, 7) [x, y, z_center, dx, dy, dz, heading] in the normalised ground frame
(x forward, y left, z up, ground at z = 0); points (N, 3+) [x, y, z, ...] [m].

Example frames are chosen automatically, the same three for every model (choose_example_frames):
- crowded: the frame with the most people whose nearest other person (BEV centre distance) is closer than
  CLOSE_M; ties go to the frame with more people, then the first frame id;
- deviating: among the other frames, the one with the most (model, person) pairs that a model found but misplaced
  (a kept prediction with BEV IoU >= FOUND_IOU but no kept prediction reaching 3D IoU 0.5); ties go to the largest
  spread between the models' mean best 3D IoU;
- easy: among the rest, frames without close pairs first, the one where the worst model finds the largest share of
  the people at 3D IoU 0.5; ties go to the highest mean best 3D IoU over all models, then the fewest people.
"Kept" predictions have score >= score_threshold, the same threshold the figure draws.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Polygon
from matplotlib.ticker import MaxNLocator

from pcdet_memslidar.geometry.boxes import boxes_to_corners_3d
from pcdet_memslidar.geometry.iou import boxes_iou3d, boxes_iou_bev
from pcdet_memslidar.geometry.mount import Mount
from pcdet_memslidar.utils.atomic import atomic_path

GT_COLOR, PRED_COLOR = "tab:blue", "tab:green"
POINT_COLOR, GROUND_COLOR, GROUND_Z = "0.3", "0.8", 0.15  # points below GROUND_Z [m] are drawn lighter
SCORE_THRESHOLD = 0.3  # predictions drawn and used for the choice of example frames
CLOSE_M = 1.5  # people closer than this (BEV centre distance) count as "close together"
FOUND_IOU = 0.1  # BEV IoU from which a prediction counts as finding a person (if misplaced when 3D IoU < 0.5)
MATCH_IOU = 0.5  # 3D IoU of a correct detection, as in the evaluation
MARGIN_M = 2.5  # view margin around the ground-truth boxes [m]
SIDE_Z = (-0.5, 3.0)  # height range of the side view [m]
LABEL_CLEARANCE_AP = 0.06  # a label goes below its point when a point this much higher is within 5 % of the time axis


@dataclass(frozen=True)
class ExampleFrame:
    """One chosen frame: its role ('easy' | 'deviating' | 'crowded'), index into the frame list, and why."""

    role: str
    index: int
    why: str


def _kept(anno: dict, score_threshold: float) -> np.ndarray:
    """(K, 7) boxes of a detection anno {'boxes_lidar', 'score'} with score >= score_threshold."""
    boxes = np.asarray(anno["boxes_lidar"], dtype=np.float64).reshape(-1, 7)
    return boxes[np.asarray(anno["score"]).reshape(-1) >= score_threshold]


def _best_ious(gt: np.ndarray, predictions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Best BEV and best 3D IoU (M,) of each ground-truth box with any prediction (0 without predictions)."""
    if len(predictions) == 0 or len(gt) == 0:
        return np.zeros(len(gt)), np.zeros(len(gt))
    return boxes_iou_bev(gt, predictions).max(axis=1), boxes_iou3d(gt, predictions).max(axis=1)


def close_people(gt: np.ndarray, close_m: float = CLOSE_M) -> int:
    """Number of boxes (M, 7) whose nearest other box centre (BEV) is closer than close_m [m]."""
    if len(gt) < 2:
        return 0
    distance = np.linalg.norm(gt[:, None, :2] - gt[None, :, :2], axis=-1)
    np.fill_diagonal(distance, np.inf)
    return int((distance.min(axis=1) < close_m).sum())


def choose_example_frames(gt_boxes: list[np.ndarray], dt_annos: dict[str, list[dict]],
                          score_threshold: float = SCORE_THRESHOLD) -> list[ExampleFrame]:
    """The easy, deviating and crowded frames (module docstring), in that order, as distinct frame indices.

    gt_boxes: per frame (M, 7); dt_annos: {model: per-frame {'boxes_lidar', 'score'}}. Frames without ground truth
    are never chosen; fewer than three such frames give fewer examples.
    """
    candidates = [index for index, boxes in enumerate(gt_boxes) if len(boxes)]
    close = {index: close_people(gt_boxes[index]) for index in candidates}
    best = {index: [_best_ious(gt_boxes[index], _kept(annos[index], score_threshold)) for annos in dt_annos.values()]
            for index in candidates}
    chosen: dict[str, ExampleFrame] = {}
    if candidates:
        crowded = max(candidates, key=lambda i: (close[i], len(gt_boxes[i]), -i))
        chosen["crowded"] = ExampleFrame("crowded", crowded, f"{close[crowded]} of {len(gt_boxes[crowded])} people "
                                         f"have a neighbour closer than {CLOSE_M} m (the most of any frame)")
        candidates.remove(crowded)

    def deviations(index: int) -> int:
        return int(sum(((bev >= FOUND_IOU) & (iou3d < MATCH_IOU)).sum() for bev, iou3d in best[index]))

    def spread(index: int) -> float:
        means = [iou3d.mean() for _, iou3d in best[index]]
        return float(max(means) - min(means)) if means else 0.0

    if candidates:
        deviating = max(candidates, key=lambda i: (deviations(i), spread(i), -i))
        chosen["deviating"] = ExampleFrame("deviating", deviating, f"{deviations(deviating)} (model, person) pairs "
                                           f"found (BEV IoU >= {FOUND_IOU}) but misplaced (3D IoU < {MATCH_IOU}); "
                                           f"spread of the models' mean best 3D IoU {spread(deviating):.2f}")
        candidates.remove(deviating)

    def worst_recall(index: int) -> float:
        return min(((iou3d >= MATCH_IOU).mean() for _, iou3d in best[index]), default=0.0)

    def mean_iou(index: int) -> float:
        return float(np.mean([iou3d.mean() for _, iou3d in best[index]])) if best[index] else 0.0

    if candidates:
        easy = max(candidates, key=lambda i: (close[i] == 0, worst_recall(i), mean_iou(i), -len(gt_boxes[i]), -i))
        count = len(gt_boxes[easy])
        chosen["easy"] = ExampleFrame("easy", easy, f"{count} {'person' if count == 1 else 'people'}; the worst "
                                      f"model finds {100 * worst_recall(easy):.0f} % at 3D IoU {MATCH_IOU} "
                                      f"(mean best 3D IoU {mean_iou(easy):.2f})")
    return [chosen[role] for role in ("easy", "deviating", "crowded") if role in chosen]


def draw_boxes_bev(ax, boxes: np.ndarray, color: str, linewidth: float = 1.2) -> None:
    """Footprints of (M, 7) boxes in a bird's-eye view (x right, y up), with a tick from the centre to the front."""
    if len(boxes) == 0:
        return
    corners = boxes_to_corners_3d(boxes)[:, :4, :2]
    for box, footprint in zip(np.asarray(boxes, dtype=np.float64), corners):
        ax.add_patch(Polygon(footprint, closed=True, fill=False, edgecolor=color, linewidth=linewidth))
        front = box[:2] + 0.5 * box[3] * np.array([np.cos(box[6]), np.sin(box[6])])
        ax.plot([box[0], front[0]], [box[1], front[1]], color=color, linewidth=linewidth)


def draw_boxes_side(ax, boxes: np.ndarray, color: str, linewidth: float = 1.2) -> None:
    """Outlines of (M, 7) boxes seen from the side (x right, z up): their x extent and height."""
    if len(boxes) == 0:
        return
    corners = boxes_to_corners_3d(boxes)
    for box_corners in corners:
        (x0, z0), (x1, z1) = box_corners[:, [0, 2]].min(axis=0), box_corners[:, [0, 2]].max(axis=0)
        ax.add_patch(Polygon([[x0, z0], [x1, z0], [x1, z1], [x0, z1]], closed=True, fill=False, edgecolor=color,
                             linewidth=linewidth))


def view_window(gt: np.ndarray, margin: float = MARGIN_M, min_extent: float = 8.0) -> tuple[np.ndarray, np.ndarray]:
    """Square BEV window (x range (2,), y range (2,)) [m] around the boxes (M, 7), at least min_extent wide."""
    corners = boxes_to_corners_3d(gt)[:, :4, :2].reshape(-1, 2)
    low, high = corners.min(axis=0) - margin, corners.max(axis=0) + margin
    half = max(min_extent, *(high - low)) / 2
    centre = (low + high) / 2
    return centre[0] + np.array([-half, half]), centre[1] + np.array([-half, half])


def plot_frame(path: str | Path, points: np.ndarray, gt_boxes: np.ndarray, title: str = "",
               predictions: np.ndarray | None = None, max_range_m: float = 45.0) -> Path:
    """A whole frame: bird's-eye view (top) and side view (bottom) of (N, 3+) points, (M, 7) ground-truth boxes
    (blue) and optional (K, 7) predicted boxes (green); ground points drawn lighter."""
    points = np.asarray(points)
    points = points[np.hypot(points[:, 0], points[:, 1]) < max_range_m]
    gt_boxes = np.asarray(gt_boxes, dtype=np.float64).reshape(-1, 7)
    predictions = np.zeros((0, 7)) if predictions is None else np.asarray(predictions, dtype=np.float64).reshape(-1, 7)
    ground = points[:, 2] < GROUND_Z
    figure = Figure(figsize=(10, 11), layout="constrained")
    bev, side = figure.subplots(2, 1, height_ratios=[3, 1])
    for mask, color in ((ground, GROUND_COLOR), (~ground, POINT_COLOR)):
        bev.scatter(points[mask, 0], points[mask, 1], s=0.2, c=color, linewidths=0)
    side.scatter(points[:, 0], points[:, 2], s=0.2, c=POINT_COLOR, linewidths=0)
    for boxes, color in ((gt_boxes, GT_COLOR), (predictions, PRED_COLOR)):
        draw_boxes_bev(bev, boxes, color)
        draw_boxes_side(side, boxes, color)
    bev.set(xlabel="x (forward) [m]", ylabel="y (left) [m]", aspect="equal",
            title=f"{title}: {len(gt_boxes)} ground-truth boxes (blue)" + (f", {len(predictions)} predicted (green)"
                                                                          if len(predictions) else ""))
    side.set(xlabel="x (forward) [m]", ylabel="z (up) [m]", aspect="equal", xlim=bev.get_xlim(),
             ylim=(SIDE_Z[0], max(SIDE_Z[1], points[:, 2].max(initial=0))))
    return save_figure(figure, path)


def plot_frames(path: str | Path, panels: list[tuple[str, np.ndarray, np.ndarray, np.ndarray]],
                point_cloud_range) -> Path:
    """Frames side by side, each a bird's-eye view over the detector's range [x0, y0, z0, x1, y1, z1] (top) and a
    side view (bottom): panels [(title, points (N, 3+), ground-truth boxes (M, 7) blue, predicted boxes (K, 7)
    green)]."""
    x0, y0, _, x1, y1, _ = np.asarray(point_cloud_range, dtype=np.float64)
    figure = Figure(figsize=(6.5 * len(panels), 8.5), layout="constrained")
    grid = figure.add_gridspec(2, len(panels), height_ratios=[3, 1])
    for column, (title, points, gt_boxes, predictions) in enumerate(panels):
        points = np.asarray(points)
        inside = (points[:, 0] >= x0) & (points[:, 0] <= x1) & (points[:, 1] >= y0) & (points[:, 1] <= y1)
        ground = points[:, 2] < GROUND_Z
        bev, side = figure.add_subplot(grid[0, column]), figure.add_subplot(grid[1, column])
        for mask, color in ((inside & ground, GROUND_COLOR), (inside & ~ground, POINT_COLOR)):
            bev.scatter(points[mask, 0], points[mask, 1], s=0.4, c=color, linewidths=0)
        side.scatter(points[inside, 0], points[inside, 2], s=0.4, c=POINT_COLOR, linewidths=0)
        for boxes, color in ((gt_boxes, GT_COLOR), (predictions, PRED_COLOR)):
            draw_boxes_bev(bev, np.asarray(boxes, dtype=np.float64).reshape(-1, 7), color)
            draw_boxes_side(side, np.asarray(boxes, dtype=np.float64).reshape(-1, 7), color)
        bev.set(xlabel="x (forward) [m]", ylabel="y (left) [m]", aspect="equal", xlim=(x0, x1), ylim=(y0, y1))
        bev.set_title(title, fontsize=9)
        side.set(xlabel="x (forward) [m]", ylabel="z (up) [m]", aspect="equal", xlim=(x0, x1), ylim=SIDE_Z)
    return save_figure(figure, path)


def plot_example_frames(path: str | Path, frames: list[dict], predictions: dict[str, list[dict]],
                        score_threshold: float = SCORE_THRESHOLD) -> Path:
    """Fig. 3-style panels: a bird's-eye and a side view per frame (rows), one column per model.

    frames: [{'points' (N, 3+), 'gt_boxes' (M, 7), 'title' str}]; predictions: {model: per-frame {'boxes_lidar',
    'score'}}, aligned with frames. Ground truth blue, predictions with score >= score_threshold green.
    """
    models = list(predictions)
    figure = Figure(figsize=(3.2 * len(models), 4.4 * len(frames)), layout="constrained")
    grid = figure.add_gridspec(2 * len(frames), len(models), height_ratios=[3, 1] * len(frames))
    for row, frame in enumerate(frames):
        points, gt = np.asarray(frame["points"]), np.asarray(frame["gt_boxes"], dtype=np.float64).reshape(-1, 7)
        x_range, y_range = view_window(gt)
        in_x = (points[:, 0] >= x_range[0]) & (points[:, 0] <= x_range[1])
        in_bev = in_x & (points[:, 1] >= y_range[0]) & (points[:, 1] <= y_range[1])
        ground = points[:, 2] < GROUND_Z
        for column, model in enumerate(models):
            shown = _kept(predictions[model][row], score_threshold)
            bev = figure.add_subplot(grid[2 * row, column])
            for mask, color in ((in_bev & ground, GROUND_COLOR), (in_bev & ~ground, POINT_COLOR)):
                bev.scatter(points[mask, 0], points[mask, 1], s=0.3, c=color, linewidths=0)
            draw_boxes_bev(bev, gt, GT_COLOR)
            draw_boxes_bev(bev, shown, PRED_COLOR)
            bev.set(xlim=x_range, ylim=y_range, aspect="equal")
            bev.set_title(f"{model}: {frame['title']}", fontsize=8)
            side = figure.add_subplot(grid[2 * row + 1, column])
            side.scatter(points[in_bev, 0], points[in_bev, 2], s=0.3, c=POINT_COLOR, linewidths=0)
            draw_boxes_side(side, gt, GT_COLOR)
            draw_boxes_side(side, shown, PRED_COLOR)
            side.set(xlim=x_range, ylim=SIDE_Z, aspect="equal")
            side.set_xlabel("x [m]", fontsize=7)
            for ax in (bev, side):
                ax.tick_params(labelsize=6)
            if column == 0:
                bev.set_ylabel("y [m]", fontsize=7)
                side.set_ylabel("z [m]", fontsize=7)
    figure.suptitle(f"ground truth (blue), predictions with score >= {score_threshold} (green)", fontsize=9)
    return save_figure(figure, path)


def plot_pr_curves(path: str | Path, curves: dict[str, dict[str, dict]], aps: dict[str, dict[str, float]]) -> Path:
    """Precision-recall curves per model, one panel per IoU kind.

    curves: {model: {'3D' | 'BEV': {'recall' (T,), 'precision' (T,)}}} (evaluate()'s pr_curves[kind]['all']);
    aps: {model: {'3D' | 'BEV': AP R40}} for the legend.
    """
    figure = Figure(figsize=(9, 4), layout="constrained")
    for column, kind in enumerate(("3D", "BEV")):
        ax = figure.add_subplot(1, 2, column + 1)
        for model, model_curves in curves.items():
            curve, ap = model_curves[kind], aps[model][kind]
            ax.plot(np.nan_to_num(np.asarray(curve["recall"], dtype=np.float64)), curve["precision"],
                    label=f"{model} (AP {'n/a' if ap is None else f'{ap:.3f}'})")
        ax.set(xlim=(0, 1), ylim=(-0.02, 1.02), xlabel="recall", ylabel="precision",
               title=f"{kind} IoU 0.5, industrial split")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc="upper right")
    return save_figure(figure, path)


def labels_below(entries: list[dict]) -> list[bool]:
    """Per entry {'ms_per_frame', 'ap'}: True where its label goes below its point, because a higher point within
    LABEL_CLEARANCE_AP sits within 5 % of the time axis (the two labels would overlap above)."""
    times = [entry["ms_per_frame"] for entry in entries]
    near_ms = 0.05 * (max(times, default=0.0) - min(times, default=0.0))
    return [any(abs(other["ms_per_frame"] - entry["ms_per_frame"]) <= near_ms
                and 0 < other["ap"] - entry["ap"] <= LABEL_CLEARANCE_AP for other in entries) for entry in entries]


def plot_ap_vs_time(path: str | Path, entries: list[dict]) -> Path:
    """AP against inference time: entries [{'name', 'ms_per_frame', 'ap', 'group'}], one marker style per group."""
    figure = Figure(figsize=(6, 4.2), layout="constrained")
    ax = figure.add_subplot(1, 1, 1)
    scored = [entry for entry in entries if entry["ap"] is not None]
    placed = list(zip(scored, labels_below(scored)))
    for group, marker in zip(dict.fromkeys(entry["group"] for entry in entries), "osD^v<>"):
        members = [(entry, below) for entry, below in placed if entry["group"] == group]
        ax.scatter([entry["ms_per_frame"] for entry, _ in members], [entry["ap"] for entry, _ in members],
                   marker=marker, label=group)
        for entry, below in members:
            ax.annotate(entry["name"], (entry["ms_per_frame"], entry["ap"]), fontsize=7,
                        xytext=(4, -10 if below else 4), textcoords="offset points")
    ax.set(xlabel="inference time [ms/frame]", ylabel="AP 3D R40 (IoU 0.5)", ylim=(-0.02, 1.02),
           title="AP on the industrial split against inference time")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return save_figure(figure, path)


def plot_ap_intervals(path: str | Path, entries: list[dict], reference: float | None = None) -> Path:
    """Each model's AP with its interval, one row per model (top to bottom in order): entries [{'name', 'ap',
    'interval' [low, high], 'paper' (AP or None)}]; the paper's AP as a cross, `reference` (the oracle's AP) as a
    dashed line."""
    figure = Figure(figsize=(6, 0.45 * len(entries) + 1.4), layout="constrained")
    ax = figure.add_subplot(1, 1, 1)
    rows = np.arange(len(entries))[::-1]
    for row, entry in zip(rows, entries):
        low, high = entry["interval"]
        ax.errorbar(entry["ap"], row, xerr=[[entry["ap"] - low], [high - entry["ap"]]], fmt="o", color="C0",
                    capsize=3, label="this run, 95 % interval" if row == rows[0] else None)
        if entry.get("paper") is not None:
            ax.plot(entry["paper"], row, "x", color="C3", label="the paper" if row == rows[0] else None)
    if reference is not None:
        ax.axvline(reference, color="gray", linestyle="--", linewidth=1, label="oracle")
    ax.set_yticks(rows, [entry["name"] for entry in entries])
    ax.set(xlabel="AP 3D R40 (IoU 0.5), industrial split", xlim=(0, 1), title="AP with bootstrap intervals")
    ax.grid(alpha=0.3, axis="x")
    figure.legend(*ax.get_legend_handles_labels(), fontsize=8, loc="outside lower center", ncols=3)  # off the rows
    return save_figure(figure, path)


def plot_training_curves(path: str | Path, curves: dict[str, list[dict]]) -> Path:
    """Training loss per epoch and validation AP against training minutes, one line per model.

    curves: {model: [{'epoch', 'minutes' (training time so far), 'loss' (mean over the epoch), 'val_AP3D_R40'}]}.
    """
    figure = Figure(figsize=(10, 4), layout="constrained")
    loss_ax, ap_ax = figure.add_subplot(1, 2, 1), figure.add_subplot(1, 2, 2)
    for model, curve in curves.items():
        epochs = [entry["epoch"] for entry in curve]
        loss_ax.plot(epochs, [entry["loss"] for entry in curve], marker="o", markersize=3, label=model)
        ap_ax.plot([entry["minutes"] for entry in curve], [entry["val_AP3D_R40"] for entry in curve], marker="o",
                   markersize=3, label=model)
    loss_ax.set(xlabel="epoch", ylabel="training loss (mean over the epoch)", title="training loss")
    ap_ax.set(xlabel="training minutes (wall clock, validation excluded)", ylabel="AP 3D R40 (IoU 0.5)",
              ylim=(-0.02, 1.02), xlim=(0, None), title="AP on its validation split after each epoch")
    loss_ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    for ax in (loss_ax, ap_ax):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    return save_figure(figure, path)


def plot_sweep(path: str | Path, lines: dict[str, list[tuple[float, list[float]]]], xlabel: str, title: str,
               log_x: bool = False) -> Path:
    """AP 3D R40 of a sweep: lines {name: [(x, [AP of each seed])]}; each seed a dot, the mean joined by a line
    with the seeds' standard deviation (n - 1) as error bars."""
    figure = Figure(figsize=(6.4, 4.2), layout="constrained")
    ax = figure.add_subplot(1, 1, 1)
    for (name, points), color in zip(lines.items(), ("tab:blue", "tab:orange", "tab:green", "tab:red")):
        xs = np.array([x for x, _ in points], dtype=np.float64)
        aps = [np.array([ap for ap in seeds if ap is not None], dtype=np.float64) for _, seeds in points]
        means = np.array([values.mean() if values.size else np.nan for values in aps])
        stds = np.array([values.std(ddof=1) if values.size > 1 else 0.0 for values in aps])
        ax.errorbar(xs, means, yerr=stds, color=color, marker="o", markersize=4, capsize=3, label=name)
        for x, values in zip(xs, aps):
            ax.scatter(np.full(values.size, x), values, color=color, s=8, alpha=0.4)
    if log_x:
        ax.set_xscale("log")
    ax.set(xlabel=xlabel, ylabel="AP 3D R40 (IoU 0.5)", ylim=(-0.02, 1.02), title=title)
    ax.title.set_fontsize(9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return save_figure(figure, path)


def plot_ground_check(path: str | Path, points: np.ndarray, mount: Mount, title: str = "",
                      floor_band_m: float = 0.1, walkable: np.ndarray | None = None) -> Path:
    """The evidence for a mount: (N, 3+) points in the SENSOR frame [m], normalised with `mount`, seen from the
    side (x, z; the fitted floor z = 0 drawn as a line) and from above (x, y; a site's walkable polygon (K, 2), if
    given, outlined); points within floor_band_m of z = 0 in orange. If the mount is right, the orange points are
    the floor, flat along x."""
    ground = mount.sensor_to_ground(np.asarray(points)[:, :3])
    floor = np.abs(ground[:, 2]) < floor_band_m
    x_range, y_range = np.percentile(ground[:, 0], [1, 99]), np.percentile(ground[:, 1], [1, 99])
    figure = Figure(figsize=(9, 10), layout="constrained")
    side, top = figure.subplots(2, 1, height_ratios=[1, 2])
    for ax, column in ((side, 2), (top, 1)):
        for mask, color, size in ((~floor, POINT_COLOR, 0.3), (floor, "tab:orange", 1.0)):
            ax.scatter(ground[mask, 0], ground[mask, column], s=size, c=color, linewidths=0)
    if walkable is not None:
        top.add_patch(Polygon(walkable, closed=True, fill=False, edgecolor="tab:green", linewidth=1.2,
                              label="walkable area"))
        top.legend(fontsize=8, loc="upper left")
    side.axhline(0.0, color="tab:blue", linewidth=1, label="fitted floor z = 0")
    side.legend(fontsize=8, loc="upper left")
    side.set(xlabel="x (forward) [m]", ylabel="z (up) [m]", aspect="equal", xlim=x_range, ylim=(-1.0, 3.0))
    top.set(xlabel="x (forward) [m]", ylabel="y (left) [m]", aspect="equal", xlim=x_range, ylim=y_range)
    evidence = (f"height {mount.height:.2f} m, tilt {mount.tilt_deg:.2f} deg, roll {mount.roll_deg:.2f} deg; orange: "
                f"{floor.mean():.1%} of the points within {floor_band_m} m of z = 0")
    side.set_title(f"{title}\n{evidence}" if title else evidence, fontsize=9)
    return save_figure(figure, path)


def save_figure(figure: Figure, path: str | Path) -> Path:
    """Write `figure` as a PNG at `path` atomically; returns the path."""
    path = Path(path)
    with atomic_path(path) as tmp:
        figure.savefig(tmp, format="png", dpi=130)
    return path
