//! The CPU time of the processes and threads the bench measures, from
//! `/proc`.

use std::collections::BTreeMap;

pub(crate) fn clock_ticks_per_s() -> f64 {
    rustix::param::clock_ticks_per_second() as f64
}

/// The run time of each thread of process `pid` now (only those whose
/// names start with `named`, if given), in ns, by thread id (the first field of
/// `/proc/PID/task/TID/schedstat`): exact, where utime + stime count whole
/// clock ticks, each charged to whoever ran when it struck. Empty if the
/// process is gone.
pub(crate) fn thread_cpu_ns(pid: u32, named: Option<&str>) -> BTreeMap<u32, u64> {
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else { return BTreeMap::new() };
    tasks
        .flatten()
        .filter_map(|task| {
            let tid = task.file_name().to_str()?.parse::<u32>().ok()?;
            if let Some(named) = named {
                let comm = std::fs::read_to_string(task.path().join("comm")).ok()?;
                if !comm.starts_with(named) {
                    return None;
                }
            }
            let stat = std::fs::read_to_string(task.path().join("schedstat")).ok()?;
            Some((tid, stat.split_whitespace().next()?.parse::<u64>().ok()?))
        })
        .collect()
}

/// The run time between two [`thread_cpu_ns`] readings, in ns, and how many
/// threads ended in between (whose time since `before` is lost: schedstat
/// dies with its thread, where utime + stime keep it). A thread that both
/// started and ended in between is neither counted nor reported.
pub(crate) fn cpu_ns_between(before: &BTreeMap<u32, u64>, after: &BTreeMap<u32, u64>) -> (u64, usize) {
    let ran = after.iter().map(|(tid, ns)| ns.saturating_sub(before.get(tid).copied().unwrap_or(0))).sum();
    (ran, before.keys().filter(|tid| !after.contains_key(tid)).count())
}

/// utime + stime of each process, in clock ticks (0 for one that is gone).
pub(crate) fn cpu_ticks(pids: &[(String, u32)]) -> Vec<u64> {
    pids.iter()
        .map(|(_, pid)| {
            let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
            // Fields after the command name, which may hold spaces, in parentheses.
            let fields: Vec<&str> = stat.rsplit_once(')').map_or(vec![], |(_, rest)| rest.split_whitespace().collect());
            let field = |n: usize| fields.get(n).and_then(|f| f.parse::<u64>().ok()).unwrap_or(0);
            field(11) + field(12)
        })
        .collect()
}
