"""Evaluate checkpoints with OpenPCDet's tools/test.py flags (see --help); same as `memslidar test`."""
import sys

from pcdet_memslidar.cli import main

if __name__ == "__main__":
    sys.exit(main(["test", *sys.argv[1:]]))
