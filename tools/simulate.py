"""Generate a simulated domain; same as `memslidar simulate` (see --help)."""
import sys

from pcdet_memslidar.cli import main

if __name__ == "__main__":
    sys.exit(main(["simulate", *sys.argv[1:]]))
