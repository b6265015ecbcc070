//! An SLCAN (Lawicel) adapter on a serial line, through `serialport`
//! (without libudev): CANable, USBtin and the like, or a pseudo-terminal
//! that an emulator holds.

use std::collections::VecDeque;
use std::io::{Read, Write};
use std::time::{Duration, Instant};

use super::CanFrame;
use super::bus::{BusError, BusUrl, CanBus, open_hint};
use super::slcan::{self, Decoder, Event};

/// The serial line's own rate. USB adapters ignore it; a real UART at this
/// rate carries about 500 frames/s, too few for a 1 Mbit/s skin bus.
const LINE_BAUD: u32 = 115_200;

/// An SLCAN adapter (`slcan:///dev/ttyACM0?bitrate=1000000`).
pub struct SlcanBus {
    port: Box<dyn serialport::SerialPort>,
    decoder: Decoder,
    received: VecDeque<CanFrame>,
    refused: usize,
    garbled: u64,
    url: String,
    buffer: Vec<u8>,
}

impl SlcanBus {
    pub(crate) fn open(url: &BusUrl<'_>) -> Result<SlcanBus, BusError> {
        url.only(&["bitrate"])?;
        let bitrate: u32 = url.option("bitrate", 1_000_000)?;
        let command = slcan::bitrate_command(bitrate).ok_or_else(|| BusError::BadUrl {
            url: url.url.to_owned(),
            problem: format!("SLCAN has no bit rate {bitrate}; use one of {}", slcan::BITRATES),
        })?;
        let port = serialport::new(url.path, LINE_BAUD).timeout(Duration::from_millis(10)).open().map_err(|e| {
            let source: std::io::Error = e.into();
            let hint = open_hint(&source, url.path);
            BusError::Open { url: url.url.to_owned(), source, hint }
        })?;
        let mut bus = SlcanBus {
            port,
            decoder: Decoder::new(),
            received: VecDeque::new(),
            refused: 0,
            garbled: 0,
            url: url.url.to_owned(),
            buffer: vec![0; 4096],
        };
        // Close first: an adapter left open by a crashed program refuses `Sn`.
        bus.write(b"C\r")?;
        bus.write(command)?;
        bus.write(b"O\r")?;
        // A refusal of the bit rate or the open comes back within a few ms.
        let deadline = Instant::now() + Duration::from_millis(50);
        while Instant::now() < deadline {
            bus.fill(Duration::from_millis(10))?;
        }
        // `C` is refused by an adapter that was already closed: allow one.
        if bus.refused > 1 {
            return Err(BusError::Refused {
                url: bus.url.clone(),
                problem: format!("the adapter refused the bit rate {bitrate} or opening the channel"),
            });
        }
        Ok(bus)
    }

    fn write(&mut self, bytes: &[u8]) -> Result<(), BusError> {
        self.port.write_all(bytes).map_err(|source| BusError::Lost { url: self.url.clone(), source })
    }

    /// Reads what the adapter sent within `timeout` into the frame queue.
    fn fill(&mut self, timeout: Duration) -> Result<(), BusError> {
        let _ = self.port.set_timeout(timeout.max(Duration::from_millis(1)));
        let read = match self.port.read(&mut self.buffer) {
            Ok(0) => {
                return Err(BusError::Lost { url: self.url.clone(), source: std::io::ErrorKind::UnexpectedEof.into() });
            }
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut || e.kind() == std::io::ErrorKind::WouldBlock => {
                return Ok(());
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => return Ok(()),
            Err(source) => return Err(BusError::Lost { url: self.url.clone(), source }),
        };
        let (received, refused, garbled) = (&mut self.received, &mut self.refused, &mut self.garbled);
        self.decoder.push(&self.buffer[..read], |event| match event {
            Event::Frame(frame, _) => received.push_back(frame),
            Event::Refused => *refused += 1,
            Event::Garbled { .. } => *garbled += 1,
            Event::Ok | Event::Transmitted | Event::Reply(_) => {}
        });
        Ok(())
    }

    /// Lines that were not frames (noise, lost bytes) since opening.
    pub fn garbled_lines(&self) -> u64 {
        self.garbled
    }
}

impl CanBus for SlcanBus {
    fn send(&mut self, frame: &CanFrame) -> Result<(), BusError> {
        let mut line = Vec::with_capacity(32);
        slcan::encode(frame, &mut line);
        self.write(&line)
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<CanFrame>, BusError> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(frame) = self.received.pop_front() {
                return Ok(Some(frame));
            }
            // At least one read, even with no time to wait.
            self.fill(deadline.saturating_duration_since(Instant::now()))?;
            if self.received.is_empty() && Instant::now() >= deadline {
                return Ok(None);
            }
        }
    }

    fn url(&self) -> &str {
        &self.url
    }
}

impl Drop for SlcanBus {
    fn drop(&mut self) {
        let _ = self.port.write_all(b"C\r");
    }
}
