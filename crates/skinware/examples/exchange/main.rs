//! A whole-skin exchange in one command: a writer publishes the paper's
//! 30,848-sensor frames at 500 Hz while readers in the three modes read them,
//! then it prints what each side measured.
//!
//! Run: `cargo run --release -p skinware --example exchange [-- SECONDS]`

use std::time::Duration;

use skinware::{Error, Reader, ReaderStats, Stop, Ticker, Writer, WriterOptions};

const SENSORS: usize = 30_848;

fn main() -> Result<(), Error> {
    let seconds: f64 = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(3.0);
    let skin = format!("example{}", std::process::id());
    let options = WriterOptions { period: Some(Duration::from_millis(2)), ..WriterOptions::default() };
    let mut writer = Writer::create(&skin, "pressure", SENSORS * 2, b"30848 taxels", &options)?;
    let stop = Stop::new();
    writer.set_stop(&stop);

    let mut handles = Vec::new();
    for mode in ["periodic", "as-soon-as-available", "on-request"] {
        let mut reader = Reader::open(&skin, "pressure")?;
        reader.set_stop(&stop);
        handles.push(std::thread::spawn(move || -> Result<(&str, ReaderStats), Error> {
            let mut ticker = Ticker::new(Duration::from_millis(10));
            loop {
                let result = match mode {
                    "periodic" => reader.next_periodic(&mut ticker).map(|_| ()),
                    "as-soon-as-available" => reader.wait_newer(Duration::from_secs(1)).map(|_| ()),
                    _ => reader.request(Duration::from_secs(1)).map(|_| ()),
                };
                match result {
                    Ok(()) | Err(Error::NoFrameYet { .. }) => {}
                    Err(Error::Stopped { .. }) => return Ok((mode, reader.stats().clone())),
                    Err(e) => return Err(e),
                }
            }
        }));
    }

    let stopper = stop.clone();
    let timer = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_secs_f64(seconds));
        stopper.stop();
    });
    let mut responses = vec![0u16; SENSORS];
    writer.run_periodic(Ticker::new(Duration::from_millis(2)), |frame| {
        // A pressure wave travelling along the skin.
        let phase = frame.seq() as usize;
        for (i, r) in responses.iter_mut().enumerate() {
            *r = ((i + phase * 64) % 4096) as u16;
        }
        frame.write_responses(0, &responses)
    })?;
    timer.join().ok();

    let stats = writer.stats();
    println!("writer  {} frames of {} sensors, {} overruns", stats.frames, SENSORS, stats.overruns);
    println!(
        "writer  write time: mean {:.1} us, max {:.1} us, p99 <= {:.1} us",
        stats.write_ns_mean as f64 / 1e3,
        stats.write_ns_max as f64 / 1e3,
        stats.write_ns_quantile(0.99) as f64 / 1e3
    );
    for handle in handles {
        let (mode, stats) = handle.join().expect("reader thread")?;
        println!(
            "reader  {mode:<22} {:>6} reads, {:>5} skipped, {} retries, read time mean {:.1} us, max {:.1} us",
            stats.reads,
            stats.skipped,
            stats.retries,
            stats.read_ns_mean() as f64 / 1e3,
            stats.read_ns_max as f64 / 1e3
        );
    }
    Ok(())
}
