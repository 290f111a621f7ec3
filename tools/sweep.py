"""The paper's open questions as sweeps over the training set (AP against the sim/real ratio or the real-annotation
budget, with figure and report); same as `memslidar sweep`.

    python tools/sweep.py ratio|real-budget [--grid P ...] --profile quick [--seeds K] [--out DIR] [--set ...]
"""
import sys

from pcdet_memslidar.cli import main

if __name__ == "__main__":
    sys.exit(main(["sweep", *sys.argv[1:]]))
