//! The soak's small helper processes, each run as a hidden role of `skin`:
//! the foreign writers (writers of an unrelated skin, which the soak
//! stops with SIGSTOP) and the CPU hog.

use std::io::Write;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use skinware::{Writer, WriterOptions};

/// The skin of the foreign writers: no skin the soak runs may be named so.
pub const FOREIGN_SKIN: &str = "soak-foreign";

/// Arguments of the hidden `bench-soak-foreign` role.
#[derive(Clone, Debug, clap::Args)]
pub struct ForeignArgs {
    /// Writers to run (1 to 100).
    #[arg(long, default_value_t = 10)]
    pub channels: usize,
}

/// Arguments of the hidden `bench-soak-hog` role.
#[derive(Clone, Debug, clap::Args)]
pub struct HogArgs {
    /// Busy threads (1 to 1024).
    #[arg(long)]
    pub threads: usize,
    /// How long they are busy.
    #[arg(long, value_parser = crate::run_options::parse_helper_seconds)]
    pub seconds: f64,
}

/// Runs `channels` writers of [`FOREIGN_SKIN`] (in the segment directory
/// of `SKINWARE_SHM_DIR`), each publishing 64 bytes at 10 Hz, until standard
/// input closes; says `ready` on standard output once all exist. Each writer
/// removes its name when it is dropped at the end.
pub fn foreign_writers(channels: usize) -> Result<()> {
    let options = WriterOptions { period: Some(Duration::from_millis(100)), ..WriterOptions::default() };
    let mut writers = Vec::new();
    for index in 0..channels {
        let name = format!("c{}-{index}", std::process::id());
        writers.push(
            Writer::create(FOREIGN_SKIN, &name, 64, b"foreign", &options)
                .with_context(|| format!("cannot create the foreign writer {FOREIGN_SKIN}/{name}"))?,
        );
    }
    let (done_tx, done_rx) = std::sync::mpsc::channel::<()>();
    std::thread::spawn(move || {
        let _ = std::io::Read::read_to_end(&mut std::io::stdin(), &mut Vec::new());
        let _ = done_tx.send(());
    });
    println!("ready");
    std::io::stdout().flush()?;
    let mut payload = [0u8; 64];
    while done_rx.recv_timeout(Duration::from_millis(100)).is_err() {
        payload[0] = payload[0].wrapping_add(1);
        for writer in &mut writers {
            let mut frame = writer.begin();
            frame.write_bytes(0, &payload)?;
            frame.publish();
        }
    }
    Ok(())
}

/// Keeps `threads` threads busy for `seconds`, at the normal priority.
pub fn hog(threads: usize, seconds: f64) -> Result<()> {
    let until = Instant::now() + Duration::try_from_secs_f64(seconds).context("the hog's seconds")?;
    let workers: Vec<_> = (0..threads.max(1))
        .map(|_| {
            std::thread::spawn(move || {
                let mut x = 1u64;
                while Instant::now() < until {
                    for _ in 0..10_000 {
                        x = std::hint::black_box(x.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1));
                    }
                }
            })
        })
        .collect();
    for worker in workers {
        let _ = worker.join();
    }
    Ok(())
}
