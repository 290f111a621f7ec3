"""Tracking metrics of `memslidar detect` on a simulated sequence (`memslidar simulate --sequence N`) for
benchmark_tracking.py beside it: CLEAR MOT (MOTA, identity switches, ...) and IDF1 from the `motmetrics` library
(pip install -e ".[bench]").

Ground truth: the labelled people of each frame (at least MIN_BOX_POINTS points) with their person ids from the
frame metadata. Hypotheses: the detections of confirmed tracks with their track ids (tentative ones are no track
yet). A track's box and a person match when their BEV centres are at most MATCH_DISTANCE_M apart.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pcdet_memslidar.errors import ConfigError, DataFormatError
from pcdet_memslidar.io.layout import KittiLayout

MATCH_DISTANCE_M = 0.5  # about a body's width: farther, the box is beside the person
IDS_PER_SEQUENCE = 1_000_000  # person and track ids of sequence s count from s x this (motmetrics takes numbers)
MOT_METRICS = ("mota", "idf1", "num_switches", "num_false_positives", "num_misses", "precision", "recall",
               "mostly_tracked", "num_unique_objects")


def sequence_truth(root: str | Path) -> list[tuple[str, list[int], np.ndarray]]:
    """(frame id, person ids (M,), BEV centres (M, 2) [m]) of each frame of a simulated sequence at `root`."""
    layout = KittiLayout(root)
    truth = []
    for frame_id in layout.frame_ids():
        path = layout.metadata(frame_id)
        metadata = json.loads(path.read_text())
        if "person_ids" not in metadata:
            raise DataFormatError(path, "has no person_ids: not a sequence; make one with `memslidar simulate "
                                        "--domain industrial --sequence N`")
        ids = metadata["person_ids"]
        centres = np.array([metadata["people"][i]["box"][:2] for i in ids], dtype=np.float64).reshape(-1, 2)
        truth.append((frame_id, ids, centres))
    return truth


def mot_metrics(sequences: list[tuple[list, list[dict]]]) -> dict:
    """MOT_METRICS over sequences [(sequence_truth, detections.jsonl records of `memslidar detect` on it)], pooled
    (ids are told apart per sequence)."""
    try:
        import motmetrics
    except ImportError:
        raise ConfigError("tracking metrics need motmetrics: pip install -e \".[bench]\"") from None
    accumulator = motmetrics.MOTAccumulator(auto_id=True)
    for sequence, (truth, records) in enumerate(sequences):
        if [frame_id for frame_id, _, _ in truth] != [record["frame"] for record in records]:
            raise ConfigError(f"sequence {sequence}: the detections do not cover its frames in order: run detect on "
                              "the sequence")
        for (_, person_ids, centres), record in zip(truth, records):
            tracked = [d for d in record["detections"] if d["track_id"] is not None]
            hypotheses = np.array([d["box"][:2] for d in tracked], dtype=np.float64).reshape(-1, 2)
            distances = motmetrics.distances.norm2squared_matrix(centres, hypotheses, max_d2=MATCH_DISTANCE_M ** 2)
            accumulator.update([sequence * IDS_PER_SEQUENCE + i for i in person_ids],
                               [sequence * IDS_PER_SEQUENCE + d["track_id"] for d in tracked], distances)
    summary = motmetrics.metrics.create().compute(accumulator, metrics=list(MOT_METRICS), name="all")
    return {name: float(summary[name].iloc[0]) for name in MOT_METRICS}
