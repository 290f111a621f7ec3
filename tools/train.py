"""Train a detector: OpenPCDet's tools/train.py flags (see `python tools/train.py --help`); same as `memslidar train`."""
import sys

from pcdet_memslidar.runtime.train import main

if __name__ == "__main__":
    sys.exit(main())
