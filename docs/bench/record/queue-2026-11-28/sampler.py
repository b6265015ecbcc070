# Samples a recorder every 0.5 s: its file thread's run and wait-for-CPU time (schedstat) and each reader
# thread's CPU time; counts the intervals in which a reader thread ran more than 40 % of the interval (a
# reader normally runs about 2 %: a higher figure is a reader spinning). Optionally moves the file thread
# to SCHED_FIFO 10 (chrt). Usage: sampler.py MCAP_PATH nice|fifo > OUT.sched
import os, sys, time, subprocess
path, variant = sys.argv[1], sys.argv[2]
def find():
    for p in os.listdir('/proc'):
        if p.isdigit():
            try:
                if f'record {path}' in open(f'/proc/{p}/cmdline').read().replace('\0', ' '): return p
            except OSError: pass
pid = None
deadline = time.time() + 90
while pid is None and time.time() < deadline: pid = find(); time.sleep(0.2)
def threads():
    out = {}
    for t in os.listdir(f'/proc/{pid}/task'):
        try: out[t] = open(f'/proc/{pid}/task/{t}/comm').read().strip()
        except OSError: pass
    return out
ft = None
while ft is None and time.time() < deadline:
    ft = next((t for t, c in threads().items() if c == 'rec-file'), None); time.sleep(0.2)
readers = [t for t, c in threads().items() if c.startswith('rec-') and c not in ('rec-file', 'rec-map', 'rec-sync')]
if variant == 'fifo': subprocess.run(['chrt', '-f', '-p', '10', ft], check=True)
def sched(t):
    r, w, _ = open(f'/proc/{pid}/task/{t}/schedstat').read().split(); return int(r), int(w)
t0 = time.time(); f0 = sched(ft); prev = {t: sched(t)[0] for t in readers}; first = dict(prev); last_f = f0
spinning = 0; worst = 0.0; killed = False
while True:
    time.sleep(0.5)
    try:
        now = {t: sched(t)[0] for t in readers}; last_f = sched(ft)
    except OSError: break
    top = max((now[t] - prev[t]) / 0.5e9 for t in readers)
    worst = max(worst, top); spinning += top > 0.4; prev = now
    if time.time() - t0 > float(sys.argv[3] if len(sys.argv) > 3 else 100) and not killed:
        os.kill(int(pid), 9); killed = True; print('killed: still running after the limit', file=sys.stderr)
span = time.time() - t0
print(f"file_run_s {(last_f[0]-f0[0])/1e9:.2f} file_wait_s {(last_f[1]-f0[1])/1e9:.2f} readers_cpu_s {sum(prev[t]-first[t] for t in readers)/1e9:.2f} "
      f"intervals_with_a_reader_over_40pct {spinning} busiest_reader_interval_pct {worst*100:.0f} over_s {span:.1f}" + (' KILLED' if killed else ''))
