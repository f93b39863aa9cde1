#!/usr/bin/env bash
# Screenshot of the native Rerun viewer showing a recording, on a machine without a display or GPU.
#
#   scripts/viewer_screenshot.sh RECORDING.rrd OUT.png [WIDTHxHEIGHT]
#
# Needs (Debian): xvfb, xdotool, mesa-vulkan-drivers (lavapipe: the viewer's OpenGL path on
# llvmpipe lacks a texture format it needs, Vulkan on lavapipe works). The pointer is parked in
# a corner so that no hover tooltip lands in the picture.
set -euo pipefail
rrd=$1; out=$2; size=${3:-1600x900}
python=${PYTHON:-python}
display=:$((90 + RANDOM % 9))
Xvfb "$display" -screen 0 3840x2160x24 -nolisten tcp >/dev/null 2>&1 &
xvfb=$!
trap 'kill $xvfb 2>/dev/null || true' EXIT
sleep 1
DISPLAY=$display xdotool mousemove 3839 2159 sleep 0.2 mousemove 3839 2159 >/dev/null
DISPLAY=$display WGPU_BACKEND=vulkan XDG_RUNTIME_DIR=${XDG_RUNTIME_DIR:-/tmp} \
    "$python" -m rerun "$rrd" --screenshot-to "$out" --window-size "$size" --port auto >/dev/null 2>&1
echo "wrote $out"
