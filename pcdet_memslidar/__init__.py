"""pcdet-memslidar: MEMS-LiDAR simulation, datasets and SECOND person detection, OpenPCDet-compatible."""
import os

__version__ = "0.2.0"

# libgomp, the OpenMP runtime that torch and numba share, lets a waiting thread spin 300,000 times before it sleeps;
# on a machine shared with other processes the spinning takes the core from the very thread it waits for, and a
# training step ran 5-6x slower beside three busy processes instead of 2-3x (tools/benchmark_load.py). libgomp reads
# this when it loads, so it applies when the package is imported before torch (the memslidar command, tools/, the
# OpenPCDet launcher). The user's choice wins: GOMP_SPINCOUNT, or OMP_WAIT_POLICY (which a GOMP_SPINCOUNT overrides).
if "OMP_WAIT_POLICY" not in os.environ:
    os.environ.setdefault("GOMP_SPINCOUNT", "10000")
