#!/usr/bin/env bash
# usage: ab.sh EXE VARIANT(nice|fifo) OUT ; one 60 s recording of the paper's skin at 1 kHz with --services (record-rss.sh),
# the recorder's file thread moved to SCHED_FIFO 10 with chrt for VARIANT=fifo; prints the file thread's run and
# wait-for-CPU seconds, the reader threads' CPU seconds, frames and lost.
set -u
exe=$1; v=$2; out=$3
python3 "$(dirname "$0")/sampler.py" $out.mcap $v > $out.sched &
sampler=$!
"$(dirname "$0")/../record-rss.sh" $exe $out 60
wait $sampler
python3 - "$out" "$(basename $exe)" "$v" <<'PY'
import json,sys
o=sys.argv[1]
try:
    j=json.load(open(o+'.json')); f, l = j['frames'], j['lost']
except Exception as e:
    f, l = 'none', 'none'
print(sys.argv[2], sys.argv[3], open(o+'.sched').read().strip(), 'frames', f, 'lost', l, flush=True)
PY
