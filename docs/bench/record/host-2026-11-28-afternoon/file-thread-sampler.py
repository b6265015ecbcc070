import os, sys, time, glob
# every 0.5 s: t, lost-ish unknown; file-thread run ns delta, wait ns delta; cpu steal/total jiffies delta; Dirty kB
pat = sys.argv[1]
def find():
    for p in os.listdir('/proc'):
        if p.isdigit():
            try:
                if pat in open(f'/proc/{p}/cmdline').read().replace('\0', ' '): return p
            except OSError: pass
def cpu():
    f = open('/proc/stat').readline().split()[1:]
    v = list(map(int, f)); return sum(v), v[7], v[3]  # total, steal, idle
pid = None
time.sleep(3)
while pid is None: pid = find(); time.sleep(0.2)
tids = {}
for t in os.listdir(f'/proc/{pid}/task'):
    tids[open(f'/proc/{pid}/task/{t}/comm').read().strip()] = t
ft = tids['rec-file']
def sched(tid):
    r, w, n = open(f'/proc/{pid}/task/{tid}/schedstat').read().split(); return int(r), int(w)
t0 = time.time(); pr = sched(ft); pc = cpu()
while True:
    time.sleep(0.5)
    try: r = sched(ft)
    except OSError: break
    c = cpu()
    dirty = [l for l in open('/proc/meminfo') if l.startswith('Dirty:')][0].split()[1]
    print(f"{time.time()-t0:.1f} file_run_ms {(r[0]-pr[0])/1e6:.0f} file_wait_ms {(r[1]-pr[1])/1e6:.0f} steal_j {c[1]-pc[1]} idle_j {c[2]-pc[2]} total_j {c[0]-pc[0]} dirty_kB {dirty}", flush=True)
    pr, pc = r, c
