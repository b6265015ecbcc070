//! Replay of a `candump -l` log at its recorded pace (or `speed` times
//! faster), once or in a loop: capture a real skin's traffic once, replay it
//! forever. Frames sent to a replay are dropped.

use std::fs::File;
use std::io::{BufRead, BufReader, Read};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use super::CanFrame;
use super::bus::{BusError, BusUrl, CanBus, open_hint};
use super::candump::{self, LogRecord};

/// A log being replayed (`candump:///path/file.log?speed=1&loop=false`).
pub struct CandumpReplay {
    path: PathBuf,
    reader: BufReader<File>,
    url: String,
    speed: f64,
    looping: bool,
    /// The first record's time, and when it was (or would have been) replayed.
    origin: Option<(u64, Instant)>,
    pending: Option<LogRecord>,
    line: Vec<u8>,
    line_number: u64,
}

impl CandumpReplay {
    pub(crate) fn open(url: &BusUrl<'_>) -> Result<CandumpReplay, BusError> {
        url.only(&["speed", "loop"])?;
        let speed: f64 = url.option("speed", 1.0)?;
        if !(speed.is_finite() && speed > 0.0) {
            return Err(BusError::BadUrl {
                url: url.url.to_owned(),
                problem: format!("speed {speed} must be above 0"),
            });
        }
        let looping: bool = url.option("loop", false)?;
        let path = PathBuf::from(url.path);
        // A log file: a FIFO there would hold the driver at its start.
        let file = skinware::shm::open_named_file(&path).map_err(|source| {
            // A log file, not an adapter: the message of a refused FIFO or
            // directory says what is there; a missing file, that it is missing.
            let hint = match source.kind() {
                std::io::ErrorKind::NotFound => {
                    format!("{} does not exist: give the path of a `candump -l` log", url.path)
                }
                std::io::ErrorKind::InvalidData => String::new(),
                _ => open_hint(&source, url.path),
            };
            BusError::Open { url: url.url.to_owned(), source, hint }
        })?;
        Ok(CandumpReplay {
            path,
            reader: BufReader::new(file),
            url: url.url.to_owned(),
            speed,
            looping,
            origin: None,
            pending: None,
            line: Vec::new(),
            line_number: 0,
        })
    }

    /// The next record of the log, rewinding at its end if looping.
    fn next_record(&mut self) -> Result<Option<LogRecord>, BusError> {
        let mut rewound = false;
        loop {
            self.line.clear();
            // A line is read at most MAX_LINE_BYTES + 1 long: the rest of a
            // longer one is skipped, so a file without line ends cannot make
            // the replay allocate without bound.
            let read = (&mut self.reader)
                .take(candump::MAX_LINE_BYTES as u64 + 1)
                .read_until(b'\n', &mut self.line)
                .map_err(|source| BusError::Lost { url: self.url.clone(), source })?;
            if read == 0 {
                if !self.looping || rewound {
                    return Ok(None);
                }
                let file = skinware::shm::open_named_file(&self.path)
                    .map_err(|source| BusError::Lost { url: self.url.clone(), source })?;
                self.reader = BufReader::new(file);
                self.origin = None;
                self.line_number = 0;
                rewound = true;
                continue;
            }
            if self.line.last() != Some(&b'\n') && self.line.len() > candump::MAX_LINE_BYTES {
                let mut rest = Vec::new();
                let _ = (&mut self.reader).take(1 << 20).read_until(b'\n', &mut rest);
            }
            self.line_number += 1;
            let text = String::from_utf8_lossy(&self.line);
            match candump::parse_line(&text) {
                Ok(Some(record)) => return Ok(Some(record)),
                Ok(None) => {}
                Err(e) => tracing::warn!(url = %self.url, line = self.line_number, error = %e, "log line skipped"),
            }
        }
    }
}

impl CanBus for CandumpReplay {
    fn send(&mut self, _frame: &CanFrame) -> Result<(), BusError> {
        Ok(())
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<CanFrame>, BusError> {
        let deadline = Instant::now() + timeout;
        let record = match self.pending.take() {
            Some(record) => record,
            None => match self.next_record()? {
                Some(record) => record,
                None => return Err(BusError::Ended { url: self.url.clone() }),
            },
        };
        let (first_us, started) = *self.origin.get_or_insert((record.time_us, Instant::now()));
        let offset = Duration::from_secs_f64(record.time_us.saturating_sub(first_us) as f64 / 1e6 / self.speed);
        let due = started + offset;
        if due > deadline {
            std::thread::sleep(deadline.saturating_duration_since(Instant::now()));
            self.pending = Some(record);
            return Ok(None);
        }
        std::thread::sleep(due.saturating_duration_since(Instant::now()));
        Ok(Some(record.frame))
    }

    fn url(&self) -> &str {
        &self.url
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_log_replays_at_its_pace_and_loops() {
        let dir = std::env::temp_dir().join(format!("skinware-candump-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("skin.log");
        std::fs::write(&path, "(100.000000) can0 405#01\n\n(100.050000) can0 407#02\n(100.100000) can0 409#03\n")
            .unwrap();
        let url = format!("candump://{}?speed=2&loop=true", path.display());
        let mut bus = crate::can::open(&url).unwrap();
        let started = Instant::now();
        let mut ids = Vec::new();
        while ids.len() < 6 {
            if let Some(frame) = bus.receive(Duration::from_millis(200)).unwrap() {
                ids.push(frame.raw_id());
            }
        }
        assert_eq!(ids, [0x405, 0x407, 0x409, 0x405, 0x407, 0x409]);
        // Two passes of 100 ms of log at speed 2: about 100 ms.
        let elapsed = started.elapsed();
        assert!(elapsed >= Duration::from_millis(95), "replayed too fast: {elapsed:?}");
        let once = format!("candump://{}?speed=100", path.display());
        let mut bus = crate::can::open(&once).unwrap();
        let mut count = 0;
        loop {
            match bus.receive(Duration::from_millis(100)) {
                Ok(Some(_)) => count += 1,
                Ok(None) => {}
                Err(BusError::Ended { .. }) => break,
                Err(e) => panic!("{e}"),
            }
        }
        assert_eq!(count, 3);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
