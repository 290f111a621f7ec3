"""Train a detector with OpenPCDet's tools/train.py flags (see --help); same as `memslidar train`."""
import sys

from pcdet_memslidar.cli import main

if __name__ == "__main__":
    sys.exit(main(["train", *sys.argv[1:]]))
