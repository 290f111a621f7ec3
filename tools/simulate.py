"""Generate a simulated domain; same as `memslidar simulate` (see --help)."""
import argparse
import sys

from pcdet_memslidar.sim import cli

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=cli.__doc__)
    cli.add_arguments(parser)
    sys.exit(cli.run(parser.parse_args()))
