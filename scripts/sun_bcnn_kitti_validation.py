"""Sun-BCNN models side by side on KITTI 07's validation frames 128-159 — the real images models are chosen on
(never 06, the real test drive): each model in the MC mode its card names, N = 25, as the node draws them.

    python scripts/sun_bcnn_kitti_validation.py --models sun_bcnn runs/sun45/ab-gradient runs/sun45/ab-sky

Prints one line per model: the median and mean vector error, zenith and azimuth median (deg) and the ANEES (with
the card's tau). ``--frames all`` judges the whole 07 clip instead (frames 0-127 are what the experiment
fine-tunes on; fine for a synthetic model that never saw them).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch
from pvo_tools.experiments.sun_bcnn import KITTI_VALIDATION_FRAMES, kitti_figures, stage_kitti
from pvo_tools.paths import data_directory


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--models", nargs="+", default=["sun_bcnn"], help="model directories or shipped names")
    parser.add_argument("--frames", choices=("validation", "all"), default="validation", help="07 frames 128-159 or 0-159")
    parser.add_argument("--data", type=Path, help="data directory (default $PVO_DATA_DIR or ../shared/data)")
    parser.add_argument("--stage", type=Path, default=Path("runs/kitti07-staged"), help="where the frames are staged")
    args = parser.parse_args()

    torch.set_num_threads(1)
    data = data_directory(args.data)
    frames = KITTI_VALIDATION_FRAMES if args.frames == "validation" else range(0, 160)
    staged = stage_kitti(data, "07", frames, args.stage / f"kitti07-{args.frames}")
    print(f"KITTI 07 frames {frames.start}-{frames.stop - 1}: {len(frames)} images")
    for name in args.models:
        f = kitti_figures(name, staged, data, "07", frames, args.stage / ".cache")
        print(
            f"{name:<40} median {f['vector_median_deg']:6.2f}  mean {f['vector_mean_deg']:6.2f}  "
            f"zenith {f['zenith_median_deg']:6.2f}  azimuth {f['azimuth_median_deg']:6.2f}  ANEES {f['anees']:6.2f}",
            flush=True,
        )


if __name__ == "__main__":
    main()
