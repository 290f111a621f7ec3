"""The site report's tables from a hand-made results dict: exact rows, 'n/a' for a set without people."""
from pcdet_memslidar.experiments.site_report import side_by_side, sites_table


def entry(ap: float | None, low: float | None = None, high: float | None = None) -> dict:
    return {"AP3D_R40": ap, "APBEV_R40": ap, "interval": {"AP3D_R40": [low, high], "APBEV_R40": [low, high]}}


def alarms(per_frame: float, fps: float) -> dict:
    return {"frames": 3, "seconds": 0.366, "detections_per_frame": per_frame, "detections_per_minute": per_frame * 491,
            "confirmed_tracks": 0, "frames_per_s": fps}


RESULTS = {"site": "room", "date": "2026-11-28T10:00:00+00:00", "command": "memslidar site train --site room.yaml",
           "wall_seconds": 600.0, "environment": {"commit": "abc123", "machine": {
               "cpu": "Some CPU", "cores": 2, "gpu": None, "vector_extensions": ["avx2", "fma"],
               "aten_cpu_capability": "AVX2", "onednn_max_cpu_isa": "AVX2"}},
           "scores": {"background": {"test": entry(0.5, 0.4, 0.6), "pairs": entry(None), "test_distractors":
                                     entry(0.25, 0.125, 0.375)}},
           "false_alarms": {"empty": {"background": alarms(0.0, 30.0)},
                            "distractors": {"background": alarms(1.5, 20.25)}}}


def test_the_side_by_side_table_gives_each_ap_with_its_interval_and_the_false_alarms():
    assert side_by_side(RESULTS)[2] == ("| background subtraction (classical) | 0.500 [0.400, 0.600] | n/a | "
                                        "0.250 [0.125, 0.375] | 0.500 [0.400, 0.600] | 0.00 (3 frames, 0.37 s) | "
                                        "1.50 (3 frames, 0.37 s) | 20.2 |")


def test_the_table_over_sites_names_each_run_and_its_machine():
    lines = sites_table([RESULTS])
    assert lines[0] == ("- room: 2026-11-28T10:00:00+00:00; Some CPU (avx2, fma; torch vector code AVX2, oneDNN up to "
                        "AVX2), 2 cores, GPU: none; commit abc123; `memslidar site train --site room.yaml`; 10.0 min")
    assert lines[-1] == ("| room | background subtraction (classical) | 0.500 [0.400, 0.600] | n/a | "
                         "0.250 [0.125, 0.375] | 0.00 (3 frames, 0.37 s) | 1.50 (3 frames, 0.37 s) | 20.2 |")
