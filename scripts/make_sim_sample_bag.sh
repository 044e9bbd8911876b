#!/usr/bin/env bash
# Re-creates bags/sim_urban_sample: 300 frames of the synthetic urban world (620x188 grey stereo,
# sun on, ground truth, sun, IMU and GPS), rendered by `pvo sim` and converted to MCAP.
set -euo pipefail
cd "$(dirname "$0")/.."
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
pvo sim "$work/sim_urban" --preset urban --frames 300 --size 620x188 --path loop --speed 8 \
  --lat 49.011 --lon 8.4245 --start-time 2011-09-30T11:30:00Z --seed 0 \
  --bag bags/sim_urban_sample --overwrite --quiet
