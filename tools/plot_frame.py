"""Draw one frame of a KITTI-layout dataset with its boxes (bird's-eye and side view) as a PNG.

    python tools/plot_frame.py data/memslidar/industrial 000012 --out frame.png [--pred PRED_LABEL_DIR]
"""
import argparse

from pcdet_memslidar.evaluation.figures import plot_frame
from pcdet_memslidar.geometry.calibration import Calibration
from pcdet_memslidar.io.kitti import boxes_from_label, read_label
from pcdet_memslidar.io.layout import KittiLayout, read_frame


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("root", help="dataset folder (KITTI layout, e.g. data/memslidar/real)")
    parser.add_argument("frame_id", help="frame id, e.g. 000012")
    parser.add_argument("--out", default=None, help="PNG to write (default <frame_id>.png)")
    parser.add_argument("--pred", default=None, help="folder of predicted KITTI labels <frame_id>.txt to draw too")
    args = parser.parse_args()
    frame = read_frame(KittiLayout(args.root), args.frame_id)
    predictions = None
    if args.pred:
        predictions = boxes_from_label(read_label(f"{args.pred}/{args.frame_id}.txt"), Calibration.virtual())
    out = plot_frame(args.out or f"{args.frame_id}.png", frame["points"], frame["gt_boxes"],
                     f"{args.root} {args.frame_id}", predictions)
    print(out)


if __name__ == "__main__":
    main()
