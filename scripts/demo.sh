#!/usr/bin/env bash
# `make demo`: the project's main job. Both embedded sample bags through the real node graph over DDS
# (stereo_vo -> simulated_sun -> fusion), recorded, evaluated, written up in runs/demo/.
set -euo pipefail
cd "$(dirname "$0")/.."
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$(( 40 + RANDOM % 50 ))}"
exec pvo demo "$@"
