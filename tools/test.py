"""Evaluate checkpoints: OpenPCDet's tools/test.py flags (see `python tools/test.py --help`); same as `memslidar test`."""
import sys

from pcdet_memslidar.runtime.test import main

if __name__ == "__main__":
    sys.exit(main())
