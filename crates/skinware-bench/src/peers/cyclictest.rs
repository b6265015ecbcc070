//! `cyclictest`'s timer wake-up latency, run beside `skin bench peers`.

use std::process::Command;

use serde::Serialize;

/// `cyclictest`'s wake-up latency, µs.
#[derive(Debug, Default, Serialize)]
pub struct Cyclictest {
    /// Median.
    pub p50: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Worst case.
    pub max: f64,
    /// Why it is missing, if it is.
    pub skipped: Option<String>,
}

/// Runs `cyclictest` (from rt-tests) for `loops` wake-ups at 1 kHz, SCHED_FIFO 80.
pub(super) fn run_cyclictest(loops: u32) -> Cyclictest {
    let output = Command::new("cyclictest")
        .args(["-q", "-m", "-p", "80", "-i", "1000", "-t", "1", "-h", "2000"])
        .args(["-l", &loops.to_string()])
        .output();
    let output = match output {
        Ok(output) if output.status.success() => output,
        Ok(output) => {
            return Cyclictest {
                skipped: Some(format!("cyclictest failed: {}", String::from_utf8_lossy(&output.stderr).trim())),
                ..Cyclictest::default()
            };
        }
        Err(e) => {
            return Cyclictest {
                skipped: Some(format!("cyclictest not found ({e}); install rt-tests")),
                ..Cyclictest::default()
            };
        }
    };
    // The histogram: one "latency_us count" line per microsecond.
    let mut histogram: Vec<(u64, u64)> = Vec::new();
    for line in String::from_utf8_lossy(&output.stdout).lines() {
        if line.starts_with('#') {
            continue;
        }
        let mut fields = line.split_whitespace();
        if let (Some(Ok(us)), Some(Ok(count))) = (fields.next().map(str::parse), fields.next().map(str::parse))
            && count > 0
        {
            histogram.push((us, count));
        }
    }
    let total: u64 = histogram.iter().map(|&(_, c)| c).sum();
    if total == 0 {
        return Cyclictest { skipped: Some("cyclictest printed no histogram".into()), ..Cyclictest::default() };
    }
    let quantile = |q: f64| {
        let rank = (q * total as f64).ceil() as u64;
        let mut seen = 0;
        for &(us, count) in &histogram {
            seen += count;
            if seen >= rank {
                return us as f64;
            }
        }
        histogram.last().map_or(0.0, |&(us, _)| us as f64)
    };
    Cyclictest {
        p50: quantile(0.5),
        p99: quantile(0.99),
        max: histogram.last().map_or(0.0, |&(us, _)| us as f64),
        skipped: None,
    }
}
