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

/// The whole machine's CPU time so far, from the `cpu` line of
/// `/proc/stat`, in clock ticks summed over its CPUs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct MachineTicks {
    /// CPUs (its `cpuN` lines).
    pub(crate) cpus: u64,
    /// Idle or waiting for I/O, from the idle loop's own clock. The busy
    /// fields (user, system, ...) are counted at clock ticks, and here they
    /// missed most of the writers' work (3.5 % busy in a window where the
    /// driver's threads ran 56.6 % of a core, by their exact run time).
    /// Busy time is what is neither idle nor stolen.
    pub(crate) idle: u64,
    /// Taken by the hypervisor from a vCPU that had work to run (steal):
    /// time in which the guest's threads, real-time ones included, could
    /// not run, whatever their priority.
    pub(crate) steal: u64,
}

impl MachineTicks {
    /// Now; `None` if `/proc/stat` cannot be read or parsed.
    pub(crate) fn now() -> Option<MachineTicks> {
        MachineTicks::parse(&std::fs::read_to_string("/proc/stat").ok()?)
    }

    /// From the text of `/proc/stat`: its `cpu` line's idle, iowait and
    /// steal fields (the 4th, 5th and 8th), and its count of `cpuN` lines.
    fn parse(stat: &str) -> Option<MachineTicks> {
        let line = stat.lines().find(|line| line.starts_with("cpu "))?;
        let fields: Vec<u64> = line.split_whitespace().skip(1).map_while(|field| field.parse().ok()).collect();
        let field = |index: usize| fields.get(index).copied();
        let cpus = stat.lines().filter(|line| line.starts_with("cpu") && !line.starts_with("cpu ")).count();
        Some(MachineTicks {
            cpus: (cpus as u64).max(1),
            idle: field(3)?.saturating_add(field(4)?),
            steal: field(7).unwrap_or(0),
        })
    }

    /// The ticks from `before` to `self`, per kind.
    pub(crate) fn since(self, before: MachineTicks) -> MachineTicks {
        MachineTicks {
            cpus: self.cpus,
            idle: self.idle.saturating_sub(before.idle),
            steal: self.steal.saturating_sub(before.steal),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::MachineTicks;

    #[test]
    fn the_machine_line_of_proc_stat_is_read_and_anything_else_is_refused() {
        let stat = "cpu  8007107 1561418 1417078 5604387 270139 0 20826 17509 0 0\ncpu0 1 2 3 4 5 6 7 8 9 10\n\
                    cpu1 1 2 3 4 5 6 7 8 9 10\nintr 5\n";
        let ticks = MachineTicks::parse(stat).unwrap();
        assert_eq!(ticks, MachineTicks { cpus: 2, idle: 5604387 + 270139, steal: 17509 });
        // An old kernel without steal; a line cut short; no cpu line; numbers that overflow.
        assert_eq!(MachineTicks::parse("cpu  1 2 3 4 5 6 7\n").unwrap().steal, 0);
        assert_eq!(MachineTicks::parse("cpu  1 2 3\n"), None);
        assert_eq!(MachineTicks::parse("intr 5\n"), None);
        let huge = format!("cpu  0 0 0 {m} {m} 0 0 0\n", m = u64::MAX);
        assert_eq!(MachineTicks::parse(&huge).unwrap().idle, u64::MAX);
        assert_eq!(ticks.since(MachineTicks { cpus: 2, idle: u64::MAX, steal: 1 }).idle, 0);
    }
}
