"""A KITTI pose file mirrored left-right: every camera pose T conjugated by S = diag(-1, 1, 1) (x right, y down,
z forward), so each right turn becomes a left turn of the same size and the drive stays a rigid motion.

    python scripts/mirror_poses.py ../shared/data/kitti/poses/10.txt runs/dpc/mirror-data/kitti/poses/10.txt

Used to render validation drives that turn the other way (`pvo_tools.dpc.render_drives` with ``data`` pointing at the
mirrored pose files): the validation drives of KITTI 03, 04 and 10 all turn right on the whole.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from pvo_core.trajectory import read_kitti_poses

MIRROR = np.diag([-1.0, 1.0, 1.0, 1.0])


def mirrored(poses: np.ndarray) -> np.ndarray:
    """(N, 4, 4) poses, each S T S."""
    return MIRROR @ poses @ MIRROR


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("poses", type=Path)
    parser.add_argument("out", type=Path)
    args = parser.parse_args()
    poses = mirrored(read_kitti_poses(args.poses))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(args.out, poses[:, :3, :].reshape(len(poses), 12), fmt="%.9e")
    print(f"{args.out}: {len(poses)} poses mirrored left-right")


if __name__ == "__main__":
    main()
