"""Each DPC-Net model's drive calibration side by side: the chosen weighing (span, axes, mean removal), its mean m-ATE
change over the validation drives and per drive, and how many candidates lowered every drive.

    python scripts/dpc_drive_choices.py runs/dpc/calibvo-lv3mi runs/dpc/calibvo-lv3mt [--all]

Reads what `pvo dpc-net calibrate --drives` wrote into each model card (no computation).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import yaml


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("models", type=Path, nargs="+")
    parser.add_argument("--all", action="store_true", help="every candidate, not only the chosen one")
    args = parser.parse_args()
    for model in args.models:
        calibration = yaml.safe_load((model / "model.yaml").read_text())["calibration"]
        drives = calibration.get("drive_calibration")
        if not drives:
            print(f"{model}: no drive calibration")
            continue
        candidates = drives["candidates"]
        accepted = sum(bool(c["accepted"]) for c in candidates.values())
        mode = "mirrored inference" if calibration.get("mirrored") else "as predicted"
        print(f"{model} ({mode}): chosen {drives['chosen']}; {accepted} of {len(candidates)} candidates lower every drive")
        for label, candidate in candidates.items():
            chosen = (
                candidate["span"] == calibration.get("vo_span")
                and candidate["axes"] == calibration.get("fused_axes")
                and candidate["remove_mean"] == bool(calibration.get("remove_mean"))
            )
            if not args.all and not chosen:
                continue
            mean = candidate["mean"]
            per_drive = " ".join(f"{d} {100 * t:+.0f}/{100 * r:+.0f}" for d, (t, r) in candidate["per_drive"].items())
            print(f"  {label:<36} mean {100 * mean[0]:+6.1f} / {100 * mean[1]:+6.1f} %   {per_drive}")


if __name__ == "__main__":
    main()
