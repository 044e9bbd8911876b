#!/usr/bin/env bash
# Re-creates bags/kitti06_sample from the real KITTI data in $PVO_DATA_DIR (default ../shared/data):
# sequence 06 frames 000000-000050 (grey stereo), ground truth, Sun-BCNN sun vectors, and the
# frames' absolute UNIX times from the KITTI raw drive 2011_09_30_drive_0020 (= odometry 06).
set -euo pipefail
cd "$(dirname "$0")/.."
data="${PVO_DATA_DIR:-$(cd .. && pwd)/shared/data}"
times="$(mktemp --suffix=.txt)"
trap 'rm -f "$times"' EXIT
python - "$data/kitti/raw-derived/2011_09_30_drive_0020_sync_KLT.mat" "$times" <<'PY'
import sys
import numpy as np
import scipy.io
t = scipy.io.loadmat(sys.argv[1])["t"].ravel()
np.savetxt(sys.argv[2], t, fmt="%.6f")
PY
pvo convert kitti "$data/kitti/sequences/06" --out bags/kitti06_sample \
  --poses "$data/kitti/sequences/06/poses_frames000-050.txt" \
  --times "$times" \
  --sun "$data/kitti/sun/kitti_sun_test_06.csv" \
  --storage mcap --overwrite "$@"
