"""Average precision of the person class (3D / BEV IoU 0.5, R40 / R11, distance bins), of label folders
(folders.evaluate_folders), reports and figures."""
from pcdet_memslidar.evaluation.metrics import DISTANCE_BINS, ap_summary, evaluate, format_results

__all__ = ["DISTANCE_BINS", "ap_summary", "evaluate", "format_results"]
