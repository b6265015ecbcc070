#!/usr/bin/env python3
"""Checks that the quick benchmark runs wrote complete, well-formed JSON.

It asserts the shape of the results, never a timing."""
import json
import sys
from pathlib import Path

out = Path(sys.argv[1])
problems = []


def need(cond, what):
    if not cond:
        problems.append(what)


def is_count(value):
    return isinstance(value, int) and value >= 0


paper = json.loads((out / "paper.json").read_text())
need(isinstance(paper, list) and len(paper) == 9, f"paper.json: expected 9 records (3 layer counts x 3 app counts), got {len(paper)}")
for record in paper:
    need({record.get("layers"), record.get("apps")} <= set(range(1, 16)), f"paper.json: bad layers/apps in {record}")
    for side in ("writer_ns", "reader_ns"):
        stats = record.get(side, {})
        for key in ("p50", "p99", "p999", "max"):
            need(is_count(stats.get(key)), f"paper.json: {side}.{key} missing in layers={record.get('layers')} apps={record.get('apps')}")
        need(stats.get("samples", 0) > 0, f"paper.json: no {side} samples in {record.get('layers')}x{record.get('apps')}")
        need(stats.get("p50", 0) <= stats.get("p99", 0) <= stats.get("p999", 0) <= stats.get("max", 0), f"paper.json: {side} percentiles out of order")
need((out / "paper.png").stat().st_size > 1000, "paper.png missing or empty")

peers = json.loads((out / "peers.json").read_text())
need(is_count(peers.get("memcpy_ns")) and peers["memcpy_ns"] > 0, "peers.json: memcpy_ns missing")
need("cyclictest_us" in peers, "peers.json: cyclictest_us missing")
for key in ("memcpy_cross_core_ns", "memcpy_woken_ns"):
    need(is_count(peers.get(key)) and peers[key] > 0, f"peers.json: {key} missing")
wake = peers.get("futex_wake_us", {})
need(all(isinstance(wake.get(k), (int, float)) and wake[k] > 0 for k in ("p50", "p99", "max")), "peers.json: futex_wake_us missing")
seen = {(r.get("system"), r.get("readers")) for r in peers.get("records", [])}
need(seen == {(s, n) for s in ("skinware", "skinware-spin", "rwlock", "iceoryx2") for n in (1, 4, 15)}, f"peers.json: records {sorted(seen)}")
for record in peers.get("records", []):
    for side in ("publish_ns", "latency_ns"):
        for key in ("p50", "p99", "max"):
            need(is_count(record.get(side, {}).get(key)), f"peers.json: {record.get('system')}/{record.get('readers')} {side}.{key} missing")
    need(isinstance(record.get("copy_vs_woken_memcpy"), (int, float)), f"peers.json: {record.get('system')}/{record.get('readers')} copy_vs_woken_memcpy missing")
    need(record.get("frames_received", 0) > 0, f"peers.json: {record.get('system')}/{record.get('readers')} received no frames")

busy = {(r.get("system"), r.get("readers")) for r in peers.get("busy_readers", [])}
need(busy == {(s, n) for s in ("skinware", "rwlock") for n in (0, 1, 4, 15)}, f"peers.json: busy_readers {sorted(busy)}")
for record in peers.get("busy_readers", []):
    for key in ("p50", "p99", "max"):
        need(is_count(record.get("publish_ns", {}).get(key)), f"peers.json: busy {record.get('system')}/{record.get('readers')} publish_ns.{key} missing")

for name, transports in (
    ("table1.json", ["memory", "memory"]),
    ("table1-slcan/table1.json", ["memory", "slcan"]),
    ("table1-ethercat/table1.json", ["ethercat", "memory"]),
):
    table1 = json.loads((out / name).read_text())
    need([row.get("name") for row in table1] == ["writer_EC", "writer_CAN", "reader_EC", "reader_CAN"], f"{name}: rows")
    for row in table1:
        need(row.get("samples", 0) > 0 and row.get("worst_ns", 0) >= row.get("avg_ns", 0) > 0, f"{name}: {row.get('name')} incomplete")
    need([row.get("transport") for row in table1[:2]] == transports, f"{name}: the writers' transport is not recorded")
    if transports[0] == "ethercat":
        after = table1[0].get("after_bus_data_ns", {})
        need(after.get("samples", 0) > 0 and is_count(after.get("p99")), f"{name}: writer_EC's span after the bus data missing")

ecat = json.loads((out / "ethercat.json").read_text())
need(ecat.get("taxels") == 708 and ecat.get("rate_hz") == 1000, "ethercat.json: not one 708-taxel segment at 1 kHz")
cycles = ecat.get("cycles", {})
need(cycles.get("cycles", 0) > 0 and cycles.get("achieved_hz", 0) > 0 and cycles.get("layer_frames_per_s", 0) > 0, "ethercat.json: no cycles")
need(is_count(cycles.get("missed_cycles")) and is_count(cycles.get("late_periods")), "ethercat.json: missed cycles not counted")
for key in ("period_ns", "jitter_ns"):
    stats = cycles.get(key, {})
    need(stats.get("samples", 0) > 0 and all(is_count(stats.get(k)) for k in ("p50", "p99", "max")), f"ethercat.json: cycles.{key} incomplete")
latency = ecat.get("latency", {})
need(latency.get("latency_ns", {}).get("samples", 0) > 0 and is_count(latency.get("skipped")), "ethercat.json: no latency samples")
need(isinstance(ecat.get("rt_refused"), list) and "cpu_wake_latency_us" in ecat, "ethercat.json: real-time settings not recorded")
faults = ecat.get("faults", [])
need([f.get("fault") for f in faults] == ["every 2nd frame lost", "every 2nd answer 20 ms late", "wrong working counter", "SubDevice leaves OP", "segment silent", "cable pull"],
     f"ethercat.json: faults {[f.get('fault') for f in faults]}")
for f in faults:
    # Every repetition is either timed or counted as not seen.
    need(len(f.get("detect_ms", [])) + f.get("undetected", -1) > 0 and len(f.get("recover_ms", [])) + f.get("unrecovered", -1) > 0,
         f"ethercat.json: {f.get('fault')}: no repetitions")

can = json.loads((out / "can.json").read_text())
need(can.get("taxels") == 768 and can.get("layer_frames_per_s", 0) > 0 and can.get("bus_frames_per_s", 0) > 0, "can.json: rates missing")
need(can.get("latency_us", {}).get("samples", 0) > 0, "can.json: no latency samples")

record = json.loads((out / "record.json").read_text())
need(record.get("taxels") == 30848, "record.json: not the paper's skin")
need(sorted(r.get("compression") for r in record.get("runs", [])) == ["lz4", "none", "zstd"], "record.json: compressions")
for run in record.get("runs", []):
    # Frames lost are measured (docs/benchmarks.md), not asserted: a CI machine may stall the recorder.
    need(run.get("frames_per_s", 0) > 0 and run.get("file_mb_per_min", 0) > 0 and is_count(run.get("lost")),
         f"record.json: {run.get('compression')} incomplete")
for key, latency in (("replay", 0), ("replay_without_wake_latency", None)):
    round_ = record.get(key, {})
    need(round_.get("requested_cpu_wake_latency_us") == latency, f"record.json: {key}: the wake latency requested")
    # CI runs as root, where the kernel grants the request.
    need(round_.get("cpu_wake_latency_us") == latency, f"record.json: {key}: the wake latency held")
    need(round_.get("replayed_frames", 0) > 0 and round_.get("identical_frames", 0) > 0, f"record.json: {key}: no replay")
    # Every frame the second recorder got is identical (the bench fails otherwise).
    need(round_.get("identical_frames", -1) + round_.get("recording_lost", -1) == round_.get("replayed_frames"),
         f"record.json: {key}: frames neither identical nor counted lost")
    for measure in ("timing_error_us", "late_us"):
        need(round_.get(measure, {}).get("samples", 0) > 0, f"record.json: {key}: no {measure} samples")

python = json.loads((out / "python.json").read_text())
need(python.get("sensors") == 30848, "python.json: not the paper's whole-skin frame")
for key in ("rust_latest", "rust_latest_to_vec", "python_latest", "python_read_into", "rust_newer_latency", "python_newer_latency"):
    stats = python.get(key, {})
    need(stats.get("samples", 0) > 0 and is_count(stats.get("p50")) and is_count(stats.get("p99")), f"python.json: {key} incomplete")
need(is_count(python.get("python_newer_skipped")), "python.json: skipped frames not counted")

wake = json.loads((out / "wake.json").read_text())
need({(r.get("wake"), r.get("readers")) for r in wake.get("records", [])} == {(w, n) for w in ("writer", "ringer", "lookout") for n in (0, 15)},
     "wake.json: configurations")
for r in wake.get("records", []):
    label = f"wake.json: {r.get('wake')}/{r.get('readers')}"
    need(r.get("frames", 0) > 0 and is_count(r.get("missed_periods")), f"{label}: no frames")
    for key in ("visible_ns", "start_late_ns", "publish_ns"):
        need(is_count(r.get(key, {}).get("p99")), f"{label}: {key} missing")
    if r.get("readers"):
        need(r.get("frames_received", 0) > 0, f"{label}: the readers received nothing")
        need(r.get(f"woken_by_{r.get('wake')}", 0) > 0, f"{label}: no wake went the chosen way")

khz = json.loads((out / "kilohertz.json").read_text())
need([p.get("phase") for p in khz.get("phases", [])] == ["control", "loaded"], "kilohertz.json: phases")
for phase in khz.get("phases", []):
    need(len(phase.get("writers", [])) == 5 and all(w.get("frames", 0) > 0 and is_count(w.get("missed_periods")) for w in phase["writers"]),
         f"kilohertz.json: {phase.get('phase')} writers incomplete")
    need(len(phase.get("cpu_percent", {})) >= 2, f"kilohertz.json: {phase.get('phase')} CPU per component missing")
loaded = (khz.get("phases") or [{}, {}])[-1]
for consumer in ("apps, asap (wait_newer)", "contact service (output visible)", "viewer → browser 1"):
    need(loaded.get("latency_us", {}).get(consumer, {}).get("samples", 0) > 0, f"kilohertz.json: no latency for {consumer}")
need(isinstance(loaded.get("recorder"), dict) and is_count(loaded["recorder"].get("lost")), "kilohertz.json: the recorder's summary")
need([v.get("browsers") for v in khz.get("viewer", [])] == [1, 10, 10], "kilohertz.json: viewer runs")
need(all(b.get("updates_per_s", 0) > 0 for v in khz.get("viewer", []) for b in v.get("per_browser", [])), "kilohertz.json: a browser got no update")
need(khz.get("viewer_cpu_ratio_10_to_1", 0) > 0, "kilohertz.json: viewer CPU ratio")
need(len(khz.get("viewer_cpu_ratios", [])) == 1, "kilohertz.json: one round of 1 and 10 browsers in a quick run")
need(all(v.get("viewer_cpu_percent", 0) > 0 and v.get("viewer_cpu_percent_ticks", -1) >= 0 and v.get("seconds", 0) > 0
         for v in khz.get("viewer", [])), "kilohertz.json: the viewer's CPU (schedstat and ticks) and its window")
need(all(v.get("viewer_threads_ended") == 0 for v in khz.get("viewer", [])),
     "kilohertz.json: a viewer thread ended inside a measured window (its CPU would be undercounted)")
need(bool(khz.get("viewer_exe")), "kilohertz.json: which executable ran the viewer")
need([f.get("browsers") for f in khz.get("floor", [])] == [1, 10], "kilohertz.json: floor server runs (1 and 10 browsers)")
need(all(f.get("cpu_percent", 0) > 0 and f.get("threads_ended") == 0 and all(b.get("updates_per_s", 0) > 0 for b in f.get("per_browser", []))
         for f in khz.get("floor", [])), "kilohertz.json: the floor server's CPU, a thread ended in its window, or a browser got no update")
cost = khz.get("browser_cost_percent", {})
# The viewer's cost per browser only exists (a quick round is noisy); the floor's, 10 browsers against 1, is above 0.
need(isinstance(cost.get("viewer"), (int, float)) and cost.get("floor", 0) > 0, "kilohertz.json: what a browser costs, viewer and floor")
need(cost.get("viewer_session", 0) > 0 and cost.get("floor_thread", 0) > 0, "kilohertz.json: each browser's own thread, viewer and floor")
need(all(0 < v.get("sessions_cpu_percent", 0) <= v.get("viewer_cpu_percent", 0) for v in khz.get("viewer", [])),
     "kilohertz.json: the viewer's session threads' CPU (above 0, within the viewer's)")
need(khz.get("viewer_cpu_ratio_at_floor", 0) > 0, "kilohertz.json: the viewer's ratio at the floor")
need(all(f.get("process_cpu_percent", 0) >= f.get("cpu_percent", 1) for f in khz.get("floor", []))
     and khz.get("floor_cpu_ratio_10_to_1", 0) > 0 and khz.get("floor_reads_skin") is False,
     "kilohertz.json: the floor server's whole CPU (at least its browser threads'), its 10/1 ratio, and that it read no skin")
need(khz.get("floor_bytes") == 61872, "kilohertz.json: the floor server's message is the viewer's update (61,872 bytes since the viewer's protocol 2)")
need(all(round(b.get("kb_per_update", 0) * 1000) == khz.get("floor_bytes") for f in khz.get("floor", []) for b in f.get("per_browser", [])),
     "kilohertz.json: every floor browser received messages of floor_bytes")

contact = json.loads((out / "contact.json").read_text())
need(contact.get("taxels") == 30848 and contact.get("detector_ns", {}).get("samples", 0) > 0, "contact.json: detector incomplete")
need(contact.get("service_frames", 0) > 0 and contact.get("service_ns_mean", 0) > 0, "contact.json: service incomplete")
khz = contact.get("service_at_1khz", {})
need(khz.get("rate_hz") == 1000 and khz.get("frames", 0) > 0 and khz.get("ns_mean", 0) > 0, "contact.json: service at 1 kHz incomplete")

follow = json.loads((out / "follow.json").read_text())
rows = {(r.get("mode"), r.get("following")) for r in follow.get("rows", [])}
need(rows == {(m, f) for m in ("periodic 1 kHz", "as soon as available", "on request", "anticipating") for f in ("watcher", "re-check")},
     f"follow.json: rows {sorted(rows)}")
for row in follow.get("rows", []):
    need(row.get("followed", 0) + row.get("missed", 0) == follow.get("restarts"), f"follow.json: {row} does not account for every restart")
    need(row.get("followed", 0) > 0 and row.get("p50_ms", -1) >= 0, f"follow.json: {row} followed no successor")
soak = json.loads((out / "soak.json").read_text())
need(soak.get("passed") is True and soak.get("failures") == [], f"soak.json: not passed: {soak.get('failures')}")
need(sum(soak.get("layers", {}).values()) == 30848 and len(soak.get("layers", {})) == 5, "soak.json: not the paper's skin")
need(soak.get("services") == ["contact", "contact-taxels", "motion"], f"soak.json: services {soak.get('services')}")
need(is_count(soak.get("seed")) and soak.get("seconds", 0) >= 110, "soak.json: seed or its two minutes of faults")
need(sorted(soak.get("readers", {})) == ["anticipate", "asap", "periodic", "request"], f"soak.json: reader modes {sorted(soak.get('readers', {}))}")
for mode, totals in soak.get("readers", {}).items():
    counts = totals.get("counts", {})
    need(counts.get("verified", 0) > 0 and totals.get("incarnations", 0) >= 1, f"soak.json: {mode} readers verified nothing")
    for key in ("torn", "backwards", "lost_counted", "lost_silently", "over_counted", "lost_at_follow", "repeats", "follows"):
        need(is_count(counts.get(key)), f"soak.json: {mode}: {key} not counted")
totals = soak.get("totals", {})
need(totals.get("verified", 0) == sum(t.get("counts", {}).get("verified", 0) for t in soak.get("readers", {}).values()),
     "soak.json: the totals are not the modes' sum")
# A round of faults holds every kind once; two minutes hold at least one round.
kinds = {"driver_sigkill", "driver_sigstop", "reader_sigkill", "reader_sigstop", "cable_pull", "foreign_stopped_writers",
         "unlink_live_name", "squat_file", "squat_fifo", "squat_symlink", "cpu_hog", "fifo_squat_driver_kill"}
need(set(soak.get("recovery", {})) == kinds, f"soak.json: fault kinds {sorted(soak.get('recovery', {}))}")
for fault in soak.get("faults", []):
    need(fault.get("kind") in kinds and fault.get("ended_s", -1) >= fault.get("injected_s", 0) > 0
         and fault.get("injected_unix_s", 0) > 1.6e9 and bool(fault.get("target")), f"soak.json: fault {fault.get('index')} incomplete")
    # Every fault is either timed or counted as not back.
    need(fault.get("back_after_end_ms") is None or fault["back_after_end_ms"] <= fault.get("back_after_injection_ms", -1),
         f"soak.json: fault {fault.get('index')}: back sooner after the end than after the injection")
for kind, recovery in soak.get("recovery", {}).items():
    need(recovery.get("count", 0) >= 1 and recovery.get("after_end_ms", {}).get("samples", 0) + recovery.get("not_back", -1) == recovery["count"],
         f"soak.json: {kind}: faults neither timed nor counted not back")
need(isinstance(soak.get("every_layer_back_within_1s"), bool), "soak.json: the 1 s goal")
names = {p.get("name") for p in soak.get("processes", [])}
need({"skin run", "driver virtual", "service contact", "service motion", "viewer", "recorder", "browser client",
      "reader periodic", "reader asap", "reader request", "reader anticipate"} <= names, f"soak.json: processes sampled {sorted(names)}")
need(all(p.get("rss_kib_max", 0) > 0 and p.get("fds_max", 0) > 0 and len(p.get("samples", [])) >= 1 for p in soak.get("processes", [])),
     "soak.json: a process's memory or descriptors missing")
need(soak.get("leaked_files") == [] and soak.get("leaked_channels") == 0 and soak.get("stuck_readers") == [],
     "soak.json: leaks or stuck readers")
need(soak.get("browser", {}).get("updates", 0) > 0, "soak.json: the viewer's browser got no update")
need(isinstance(soak.get("recorder"), dict) and soak["recorder"].get("frames", 0) > 0, "soak.json: the recorder's summary")

c_api = json.loads((out / "c.json").read_text())
for key in ("rust_latest", "c_latest", "rust_periodic_lateness", "cpp_periodic_lateness"):
    stats = c_api.get(key, {})
    need(stats.get("samples", 0) > 0 and is_count(stats.get("p50")) and stats.get("p50", 0) <= stats.get("p99", 0) <= stats.get("max", 0),
         f"c.json: {key} missing or out of order")
need(c_api.get("latest_ratio_p50", 0) > 0 and c_api.get("latest_ratio_mean", 0) > 0, "c.json: the latest() ratios")
need(all(c_api.get("sizes", {}).get(k, 0) > 0 for k in ("header", "cpp_header", "shared_library", "static_library")),
     "c.json: the installed files' sizes")

recorder = json.loads((out / "recorder.json").read_text())
runs = {r.get("compression"): r for r in recorder.get("runs", [])}
need(set(runs) == {"zstd", "lz4", "none"}, f"recorder.json: compressions {sorted(runs)}")
for name, r in runs.items():
    need(r.get("frames", 0) > 0 and is_count(r.get("lost")) and is_count(r.get("file_waits")), f"recorder.json: {name}: frames or losses")
    need(r.get("message_mb_per_s", 0) > 0 and r.get("file_mb_per_s", 0) > 0 and r.get("cpu_percent", 0) > 0, f"recorder.json: {name}: MB/s or CPU")
    need(len(r.get("rss_kib", [])) >= 1 and all(is_count(k) and k > 0 for k in r["rss_kib"]), f"recorder.json: {name}: memory samples")
plain = recorder.get("plain_write", {})
need(plain.get("bytes", 0) > 0 and plain.get("paced_mb_per_s", 0) > 0 and plain.get("fastest_mb_per_s", 0) > 0, "recorder.json: the plain write")

scale = json.loads((out / "scale.json").read_text())
points = scale.get("points", [])
need(len(points) == 16, f"scale.json: expected 16 points (4 sizes x 2 rates x 0/15 readers), got {len(points)}")
for p in points:
    where = f"scale.json: {p.get('taxels')} taxels at {p.get('rate_hz')} Hz with {p.get('readers')} readers"
    need(p.get("frame_bytes") == 2 * p.get("taxels", -1), f"{where}: frame bytes")
    for key in ("publish_ns", "memcpy_ns"):
        stats = p.get(key, {})
        need(stats.get("samples", 0) > 0 and 0 < stats.get("p50", 0) <= stats.get("p99", 0) <= stats.get("max", 0), f"{where}: {key}")
    need(is_count(p.get("missed_periods")) and is_count(p.get("overrun_missed")) and p["overrun_missed"] <= p["missed_periods"], f"{where}: missed periods")
    need(p.get("periods", 0) > 0 and p.get("writer_thread_cpu_percent", 0) > 0, f"{where}: periods or writer CPU")
    if p.get("readers", 0) > 0:
        need(p.get("waiting_copy_ns", {}).get("samples", 0) > 0 and p.get("waiting_latency_ns", {}).get("samples", 0) > 0, f"{where}: readers' samples")
        need(p.get("readers_cpu_percent", 0) > 0, f"{where}: readers' CPU")
need(len(scale.get("frontier", [])) == 2, "scale.json: a frontier per rate")
need((out / "scale.png").stat().st_size > 1000, "scale.png missing or empty")

if problems:
    print("benchmark JSON problems:\n  " + "\n  ".join(problems))
    sys.exit(1)
print(f"benchmark JSON complete: {len(paper)} paper records, {len(peers['records'])} peer records ({len(peers['busy_readers'])} busy), {len(table1)} table rows")
