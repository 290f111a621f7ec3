"""The detectors of several `memslidar site train` runs in one table (markdown, for README and docs): per site and
detector AP 3D R40 with its interval on each held-out set with people, false alarms without people, frames per
second; above it, one line per run with its date, CPU and command.

    python tools/site_table.py output/site/blickfeld_room output/site/doorway output/site/open_hall
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from pcdet_memslidar.experiments.site_report import sites_table


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("runs", type=Path, nargs="+", help="`memslidar site train` output folders")
    args = parser.parse_args()
    print("\n".join(sites_table([json.loads((run / "results.json").read_text()) for run in args.runs])))


if __name__ == "__main__":
    main()
