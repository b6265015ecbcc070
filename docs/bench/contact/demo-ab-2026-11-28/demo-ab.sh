#!/bin/bash
# The contact service's cost in `skin demo`'s skin, builds in turn.
#
# usage: demo-ab.sh ROUNDS WINDOW_S SKIN_EXE...
#
# For each round and each `skin` executable given: starts `skin run
# examples/demo.toml` with it, waits DELAY seconds (8 unless set), and over the next WINDOW_S seconds
# reads what `skin services --json` reports for the contact service at both
# ends (frames and running mean: the window's own mean from the two) and the
# service thread's CPU time from /proc (schedstat: its whole loop, waking and
# sleeping included). Prints, per run: the executable, frames, the window's
# mean cost (µs, what `skin services` prints) and CPU per frame (µs).
# Run it from the repository, with nothing else running.
set -eu
rounds=$1; window=$2; shift 2
cd "$(git rev-parse --show-toplevel)"
log=$(mktemp)
contact_stats() {
  "$1" services --json | python3 -c "import json,sys; d=[s for s in json.load(sys.stdin)['services'] if s['name']=='contact'][0]; print(d['frames'], d['cost_ns_mean'])"
}
for _ in $(seq "$rounds"); do
  for exe in "$@"; do
    "$exe" run examples/demo.toml > "$log" 2>&1 &
    pid=$!
    sleep "${DELAY:-8}"
    service=$(pgrep -f "service $PWD/examples/demo.toml --name contact")
    before=$(contact_stats "$exe"); cpu_before=$(cut -d' ' -f1 "/proc/$service/task/$service/schedstat")
    sleep "$window"
    after=$(contact_stats "$exe"); cpu_after=$(cut -d' ' -f1 "/proc/$service/task/$service/schedstat")
    kill -INT "$pid"; wait "$pid" 2>/dev/null || true
    python3 -c "
a = list(map(int, '$before'.split())); c = list(map(int, '$after'.split()))
n = c[0] - a[0]
print('$(basename "$exe")', n, 'cost', round((c[0] * c[1] - a[0] * a[1]) / n / 1000, 1), 'cpu/frame', round(($cpu_after - $cpu_before) / n / 1000, 1))"
    sleep 1
  done
done
rm -f "$log"
