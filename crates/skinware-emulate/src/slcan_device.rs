//! The device end of an SLCAN adapter on a pseudo-terminal.

use std::io::{Read, Write};
use std::time::{Duration, Instant};

use serialport::{SerialPort, TTYPort};
use skinware_drivers::can::CanFrame;
use skinware_drivers::can::slcan::{self, Decoder, Event};

use crate::DeviceLink;

/// An SLCAN adapter as the host sees it, at `slcan:///dev/pts/N`: it
/// acknowledges `C`, `Sn`, `O` and the rest with `\r`, passes the host's
/// frames on, and sends frames to the host only while the channel is open.
pub struct SlcanDevice {
    master: TTYPort,
    path: String,
    decoder: Decoder,
    open: bool,
    buffer: Vec<u8>,
    dropped: u64,
}

impl SlcanDevice {
    /// Opens a pseudo-terminal. Nothing holds its host end until the host opens it.
    pub fn new() -> std::io::Result<SlcanDevice> {
        let (master, slave) = TTYPort::pair().map_err(std::io::Error::from)?;
        let path = slave.name().ok_or_else(|| std::io::Error::other("the pseudo-terminal has no name"))?;
        drop(slave);
        Ok(SlcanDevice { master, path, decoder: Decoder::new(), open: false, buffer: vec![0; 4096], dropped: 0 })
    }

    /// The host's end, e.g. `/dev/pts/3`.
    pub fn path(&self) -> &str {
        &self.path
    }

    /// The URL a host opens it with.
    pub fn url(&self) -> String {
        format!("slcan://{}?bitrate=1000000", self.path)
    }

    /// Frames that could not be written (no host, or a host not reading).
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    fn answer(&mut self, bytes: &[u8]) {
        let _ = self.master.write_all(bytes);
    }
}

impl DeviceLink for SlcanDevice {
    fn poll(&mut self, timeout: Duration) -> std::io::Result<Vec<CanFrame>> {
        let deadline = Instant::now() + timeout;
        let mut frames = Vec::new();
        loop {
            // At least one read, however short the wait: a caller polling
            // with no time to spare must still hear the host.
            let left = deadline.saturating_duration_since(Instant::now()).max(Duration::from_millis(1));
            let _ = self.master.set_timeout(left);
            let read = match self.master.read(&mut self.buffer) {
                Ok(n) => n,
                Err(e) if matches!(e.kind(), std::io::ErrorKind::TimedOut | std::io::ErrorKind::WouldBlock) => 0,
                // EIO: no host holds the other end (yet, or any more).
                Err(_) => {
                    self.open = false;
                    std::thread::sleep(left.min(Duration::from_millis(10)));
                    0
                }
            };
            let mut events = Vec::new();
            self.decoder.push(&self.buffer[..read], |event| events.push(event));
            for event in events {
                match event {
                    Event::Frame(frame, _) => {
                        frames.push(frame);
                        self.answer(if frame.is_extended() { b"Z\r" } else { b"z\r" });
                    }
                    Event::Reply(command) => {
                        match command.as_bytes().first() {
                            Some(b'O') => self.open = true,
                            Some(b'C') => self.open = false,
                            _ => {}
                        }
                        let known =
                            matches!(command.as_bytes().first(), Some(b'O' | b'C' | b'S' | b'V' | b'N' | b'F' | b'Z'));
                        self.answer(if known { b"\r" } else { b"\x07" });
                    }
                    Event::Ok | Event::Refused | Event::Transmitted | Event::Garbled { .. } => {}
                }
            }
            if Instant::now() >= deadline {
                return Ok(frames);
            }
        }
    }

    fn send(&mut self, frame: &CanFrame) -> std::io::Result<()> {
        if !self.open {
            self.dropped += 1;
            return Ok(());
        }
        let mut line = Vec::with_capacity(32);
        slcan::encode(frame, &mut line);
        let _ = self.master.set_timeout(Duration::from_millis(5));
        if self.master.write_all(&line).is_err() {
            self.dropped += 1;
        }
        Ok(())
    }
}
