#!/usr/bin/env bash
# The recorder's memory over a long recording: the paper's skin with every
# layer and both services at 1 kHz (examples/paper-virtual-skin.toml at
# 1 kHz, as `skin bench recorder` runs it), `skin record --services` for
# SECONDS with any further options of skin record (--split-seconds 30, say),
# and its resident memory read from /proc every 10 s (from the recorder's
# start, which waits up to 60 s for the skin to come up: about 5 s here).
#
# Usage: docs/bench/record/record-rss.sh SKIN_EXE OUT_PREFIX SECONDS [skin record options...]
# Writes OUT_PREFIX.rss (seconds and KiB, one line per sample) and
# OUT_PREFIX.json (skin record's summary); removes the recording itself.
set -euo pipefail
exe=$1; out=$2; seconds=$3; shift 3
repo="$(cd "$(dirname "$0")/../../.." && pwd)"
export SKINWARE_SHM_DIR="/dev/shm/record-rss-$$"
mkdir -p "$SKINWARE_SHM_DIR"
sed -e 's/rate_hz = { random = \[30, 50\] }/rate_hz = 1000/' -e 's/^rate_hz = 50$/rate_hz = 1000/' -e '/^slots = 3$/d' \
  "$repo/examples/paper-virtual-skin.toml" > "$out.skin.toml"
"$exe" run "$out.skin.toml" > "$out.skin.log" 2>&1 &
skin=$!
recorder=""
# However it ends (Ctrl-C too): the recorder and the skin stopped, the recording removed.
trap 'kill -INT $recorder $skin 2>/dev/null; wait 2>/dev/null; rm -f "$out.mcap" "$out"_[0-9][0-9][0-9]*.mcap; rm -rf "$SKINWARE_SHM_DIR"' EXIT
"$exe" record "$out.mcap" --services --wait 60 --seconds "$seconds" --json "$@" > "$out.json" 2> "$out.err" &
recorder=$!
started=$(date +%s)
while kill -0 "$recorder" 2>/dev/null; do
  rss=$(awk '/VmRSS/ {print $2}' "/proc/$recorder/status" 2>/dev/null || true)
  [ -n "$rss" ] && echo "$(( $(date +%s) - started )) $rss"
  sleep 10
done > "$out.rss"
wait "$recorder"
