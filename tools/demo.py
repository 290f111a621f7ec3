"""Run a trained detector on recordings with OpenPCDet's demo.py flags (--cfg_file --data_path --ckpt --ext); same
as `memslidar detect`, which also tracks people and raises zone events (see --help)."""
import sys

from pcdet_memslidar.cli import main

if __name__ == "__main__":
    sys.exit(main(["detect", *sys.argv[1:]]))
