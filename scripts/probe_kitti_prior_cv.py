"""PROBE-GK's prior for KITTI's KLT tracks, chosen by three-fold cross-validation on drive 07's frames 1-499
(drive 06 is the test drive of `pvo experiment probe`, 01 is kept for testing): each fold trains on two blocks of
frames and validates on the third; the figure is PROBE-GK-GT's change of translational ARMSE against the static
M-estimator, per fold and their mean.

    python scripts/probe_kitti_prior_cv.py [--data ../shared/data]

The README and `pvo_tools.experiments.probe.KITTI_PRIOR` quote its output (about 2 min).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from pvo_core.readers import read_klt_tracks
from pvo_frontend.probe.evaluation import tracks_experiment
from pvo_frontend.probe.gk import GKConfig
from pvo_frontend.probe.predictors import PredictorConfig

CANDIDATES = {
    "nominal": GKConfig(prior="nominal"),
    "fitted, 1 dof": GKConfig(prior_dof=1.0),
    "fitted, 3 dof": GKConfig(prior_dof=3.0),
}
PREDICTORS = {"tracks + IMU": PredictorConfig(image=False, imu=True), "tracks": PredictorConfig(image=False)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=Path("../shared/data"), help="the shared data directory")
    args = parser.parse_args()
    tracks = read_klt_tracks(args.data / "kitti" / "raw-derived" / "2011_09_30_drive_0027_sync_KLT.mat")
    n = len(tracks)
    edges = [1, 167, 333, n]
    for label, predictors in PREDICTORS.items():
        for name, gk in CANDIDATES.items():
            changes = []
            for fold in range(3):
                validation = range(edges[fold], edges[fold + 1])
                train = [k for k in range(1, n) if k not in validation]
                table = tracks_experiment(tracks, tracks, predictors, train, validation, gk=gk, em_iterations=2)
                changes.append(table.change("PROBE-GK-GT", against="Static M-estimator"))
            folds = " ".join(f"{100 * c:+.1f}" for c in changes)
            print(f"{label}, {name}: folds {folds} %, mean {100 * np.mean(changes):+.1f} %", flush=True)


if __name__ == "__main__":
    main()
