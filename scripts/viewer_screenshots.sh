#!/usr/bin/env bash
# The documentation's screenshots of the live view, taken in a real browser.
#
#   scripts/viewer_screenshots.sh [OUT_DIR]        (default docs/images)
#
# For the RobotCar day/night pair and the nuScenes front/rear scene in ../shared/data it
# builds the map, runs `lostx match --web` on the queries, and photographs the web viewer
# in headless Chromium in the light and the dark theme at 1280 x 720 and 1600 x 1000.
#
# Needs: Debian's chromium (`apt-get install chromium`), node and, once,
# `npm install --prefix scripts` (Playwright's driver, no browser download). Run from the
# repository root with the project's venv (`PYTHON=.venv/bin/python` by default).
set -euo pipefail
out=${1:-docs/images}
lostx=(${PYTHON:-.venv/bin/python} -m lostx.cli)
data=${LOSTX_DATA:-../shared/data}
work=$(mktemp -d)
pids=()
cleanup() {
  for pid in "${pids[@]}"; do kill -TERM "$pid" 2>/dev/null || true; done
  wait 2>/dev/null || true
  rm -rf "$work"
}
trap cleanup EXIT
mkdir -p "$out"

# shoot NAME MAP QUERIES [MATCH OPTIONS...]: serve one run's view and photograph it.
shoot() {
  local name=$1 map=$2 queries=$3
  shift 3
  "${lostx[@]}" match "$map" "$queries" --out "$work/$name.csv" --quiet --web --web-port 0 --grpc-port 0 \
    --viewer-rate 0 "$@" >"$work/$name.out" 2>"$work/$name.err" &
  local pid=$!
  pids+=("$pid")
  local url=""
  for _ in $(seq 600); do
    url=$(grep -o 'serving the web viewer at http://[^ ]*' "$work/$name.err" | cut -d' ' -f6 || true)
    [[ -n $url ]] && break
    kill -0 "$pid" 2>/dev/null || { cat "$work/$name.err" >&2; exit 1; }
    sleep 0.5
  done
  [[ -n $url ]] || { echo "no web viewer URL from lostx match" >&2; exit 1; }
  cat "$work/$name.out"
  node scripts/viewer_screenshots.mjs "$url" "$out/viewer-$name" 1280x720 1600x1000
  kill -TERM "$pid"
  wait "$pid"
}

"${lostx[@]}" map build "$data/robotcar-daynight/day" --out "$work/robotcar-day.map" --quiet
shoot robotcar "$work/robotcar-day.map" "$data/robotcar-daynight/night" --sequence --window 3

scene=$data/nuscenes-frontrear/scene-0523
# The paper's setup: the map from the rear camera, the front camera's frames as queries. The
# folders are read as nuScenes (the tables lie above them), which takes no positions file:
# --look-at 15 gives the points 15 m along the camera's axis (positions_lookat15m.csv), on
# both sides so that the map's true position of a query is comparable with its answer's.
"${lostx[@]}" map build "$scene/rear" --camera rear --look-at 15 --out "$work/nuscenes-rear.map" --quiet
shoot nuscenes "$work/nuscenes-rear.map" "$scene/front" --look-at 15 --opposite --sequence
