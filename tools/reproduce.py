"""The paper's M1-M4 reproduction (data, four SECOND models, Table 3, figures, report); same as `memslidar reproduce`.

    python tools/reproduce.py --profile quick [--seeds K] [--out DIR] [--data-root DIR] [--set KEY VALUE ...]
"""
import sys

from pcdet_memslidar.cli import main

if __name__ == "__main__":
    sys.exit(main(["reproduce", *sys.argv[1:]]))
