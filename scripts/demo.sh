#!/usr/bin/env bash
# `make demo`: the project's main job on the embedded sample bag. For now: replay the real KITTI 06
# sample through the graph's input topics, record it back with `pvo bag record`, and compare.
set -euo pipefail
cd "$(dirname "$0")/.."
bag="${1:-bags/kitti06_sample}"
run_dir="runs/demo"
rm -rf "$run_dir" && mkdir -p "$run_dir"
export ROS_DOMAIN_ID="${ROS_DOMAIN_ID:-$(( 40 + RANDOM % 50 ))}"
topics=(/stereo/left/image_rect /stereo/right/image_rect /stereo/left/camera_info /stereo/right/camera_info
        /ground_truth/odometry /ground_truth/sun_direction)

echo "== source bag =="
pvo bag info "$bag"

echo
echo "== replay -> record (ROS_DOMAIN_ID=$ROS_DOMAIN_ID) =="
pvo bag record -o "$run_dir/recorded" --stamp header "${topics[@]}" &
recorder=$!
trap 'kill -INT $recorder 2>/dev/null || true' EXIT
pvo bag play "$bag" --rate 2 --wait-for-subscribers 1
sleep 1
kill -INT "$recorder"
wait "$recorder"
trap - EXIT

echo
echo "== recorded bag =="
pvo bag info "$run_dir/recorded"

echo
echo "== ground truth =="
pvo bag trajectory "$run_dir/recorded" --output "$run_dir/ground_truth_kitti.txt"
echo
echo "demo outputs in $run_dir/"
