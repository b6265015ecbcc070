//! iCub MTB boards in software.

use std::io::Write;
use std::time::{Duration, Instant};

use skinware_drivers::PressureField;
use skinware_drivers::can::candump::{self, LogRecord};
use skinware_drivers::can::icub_mtb::{self, Message, SET_BOARD_CONFIG, SET_TRIANGLE_CONFIG, SET_TX_MODE};
use skinware_drivers::can::{CanFrame, icub_mtb::TAXELS_PER_TRIANGLE};
use skinware_drivers::virtual_skin::BASELINE;

use crate::DeviceLink;

/// What the boards do wrong, on purpose.
#[derive(Clone, Debug, Default)]
pub struct MtbFaults {
    /// Never send a triangle's tail frame.
    pub drop_tails: bool,
    /// Report this error code (1 no-ack, 2 not connected) in every tail.
    pub error_nibble: Option<u8>,
    /// Stop sending anything this long after streaming starts.
    pub silence_after: Option<Duration>,
}

#[derive(Clone, Debug)]
struct Board {
    address: u8,
    triangles: u8,
    period_ms: u8,
    no_load: u8,
    enabled: (u8, u8),
    streaming: bool,
}

/// A bus of MTB boards, addresses 1..=B, each with T triangles. A board
/// streams once the host starts it, at the period the host configured (or
/// the one given here), with the no-load value the host configured.
#[derive(Clone, Debug)]
pub struct MtbBoards {
    boards: Vec<Board>,
    faults: MtbFaults,
    streaming_since: Option<Instant>,
}

impl MtbBoards {
    /// `boards` boards of `triangles` triangles, streaming every `period`
    /// until the host configures another.
    pub fn new(boards: u8, triangles: u8, period: Duration, faults: MtbFaults) -> MtbBoards {
        let period_ms = period.as_millis().clamp(1, 255) as u8;
        let boards = (1..=boards.min(15))
            .map(|address| Board {
                address,
                triangles: triangles.min(16),
                period_ms,
                no_load: 245,
                enabled: (0, triangles.min(16).saturating_sub(1)),
                streaming: false,
            })
            .collect();
        MtbBoards { boards, faults, streaming_since: None }
    }

    /// Taxels on the bus.
    pub fn taxels(&self) -> usize {
        self.boards.iter().map(|b| usize::from(b.triangles) * TAXELS_PER_TRIANGLE).sum()
    }

    /// Obeys a command from the host (other frames are ignored).
    pub fn obey(&mut self, frame: &CanFrame) {
        let Message::Command { board, bytes, len } = icub_mtb::parse(frame) else { return };
        let Some(target) = self.boards.iter_mut().find(|b| b.address == board) else { return };
        match (bytes[0], len) {
            (SET_BOARD_CONFIG, 4) => {
                target.period_ms = bytes[2].max(1);
                target.no_load = bytes[3];
            }
            (SET_TRIANGLE_CONFIG, 7) => target.enabled = (bytes[1], bytes[2]),
            (SET_TX_MODE, 2) => {
                target.streaming = bytes[1] == 0;
                if target.streaming && self.streaming_since.is_none() {
                    self.streaming_since = Some(Instant::now());
                }
            }
            _ => {}
        }
    }

    /// The period of the fastest streaming board, if any streams.
    pub fn period(&self) -> Option<Duration> {
        self.boards.iter().filter(|b| b.streaming).map(|b| Duration::from_millis(u64::from(b.period_ms))).min()
    }

    /// One period's frames: every streaming board's enabled triangles, their
    /// taxels reading `responses` (global taxel order, board by board) as
    /// an MTB would: `no_load` untouched, lower under pressure.
    pub fn frames(&self, responses: &[u16]) -> Vec<CanFrame> {
        let silenced = match (self.faults.silence_after, self.streaming_since) {
            (Some(after), Some(since)) => since.elapsed() >= after,
            _ => false,
        };
        let mut frames = Vec::new();
        if silenced {
            return frames;
        }
        let mut first = 0;
        for board in &self.boards {
            for triangle in 0..board.triangles {
                let taxels = first + usize::from(triangle) * TAXELS_PER_TRIANGLE;
                if !board.streaming || triangle < board.enabled.0 || triangle > board.enabled.1 {
                    continue;
                }
                let raw: [u8; TAXELS_PER_TRIANGLE] = std::array::from_fn(|k| {
                    let response = responses.get(taxels + k).copied().unwrap_or(BASELINE);
                    raw_value(response, board.no_load)
                });
                let error = self.faults.error_nibble.unwrap_or(0);
                let [head, tail] = icub_mtb::triangle_frames(board.address, triangle, &raw, 0, error);
                frames.push(head);
                if !self.faults.drop_tails {
                    frames.push(tail);
                }
            }
            first += usize::from(board.triangles) * TAXELS_PER_TRIANGLE;
        }
        frames
    }
}

/// What an MTB reports for a virtual response: `no_load` at the baseline,
/// one count lower per 100 of pressure, down to 0.
pub fn raw_value(response: u16, no_load: u8) -> u8 {
    let pressed = response.saturating_sub(BASELINE) / 100;
    no_load.saturating_sub(pressed.min(255) as u8)
}

/// What the emulated taxels feel: fills the bus's responses (virtual
/// responses, [`BASELINE`] untouched) for a time in seconds since the start.
pub type Touch<'a> = &'a (dyn Fn(f64, &mut [u16]) + Sync);

/// The virtual body's moving contacts as a [`Touch`].
pub fn contacts(field: &PressureField) -> impl Fn(f64, &mut [u16]) + Sync + '_ {
    move |t, responses| field.responses(t, 0, responses)
}

/// Runs `boards` on `link` until `stop` returns true: obeys the host, and
/// each period sends the frames of what `touch` says the taxels feel. If
/// `log` is given, every frame sent is written to it as a `candump -l` line.
pub fn run_mtb(
    boards: &mut MtbBoards,
    link: &mut dyn DeviceLink,
    touch: Touch<'_>,
    mut log: Option<&mut dyn Write>,
    stop: &dyn Fn() -> bool,
) -> std::io::Result<u64> {
    let started = Instant::now();
    let mut responses = vec![BASELINE; boards.taxels()];
    let mut next = Instant::now();
    let mut sent = 0u64;
    while !stop() {
        let wait = next.saturating_duration_since(Instant::now()).min(Duration::from_millis(20));
        for frame in link.poll(wait)? {
            boards.obey(&frame);
        }
        let Some(period) = boards.period() else {
            next = Instant::now();
            continue;
        };
        if Instant::now() < next {
            continue;
        }
        next += period;
        if next < Instant::now() {
            next = Instant::now() + period;
        }
        touch(started.elapsed().as_secs_f64(), &mut responses);
        let wall_us = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_micros() as u64)
            .unwrap_or(0);
        for frame in boards.frames(&responses) {
            link.send(&frame)?;
            sent += 1;
            if let Some(log) = log.as_deref_mut() {
                let record = LogRecord { time_us: wall_us, interface: "mtb0".into(), frame };
                writeln!(log, "{}", candump::format_line(&record))?;
            }
        }
    }
    Ok(sent)
}

#[cfg(test)]
mod tests {
    use super::*;
    use skinware_drivers::can::icub_mtb::{Board as HostBoard, BoardSettings, start_commands, stop_commands};

    #[test]
    fn boards_obey_the_host() {
        let mut boards = MtbBoards::new(2, 4, Duration::from_millis(40), MtbFaults::default());
        assert_eq!(boards.period(), None, "nothing streams before the start command");
        let host =
            [HostBoard { address: 1, triangles: vec![0, 1, 2, 3] }, HostBoard { address: 2, triangles: vec![0, 1] }];
        let settings = BoardSettings { period_ms: 20, no_load: 240, ..BoardSettings::default() };
        for frame in start_commands(&host, &settings) {
            boards.obey(&frame);
        }
        assert_eq!(boards.period(), Some(Duration::from_millis(20)));
        let mut responses = vec![BASELINE; boards.taxels()];
        responses[13] = BASELINE + 1000; // board 1, triangle 1, taxel 1
        let frames = boards.frames(&responses);
        assert_eq!(frames.len(), 2 * (4 + 2), "board 2 enables triangles 0..=1");
        let Message::Head { board: 1, triangle: 1, raw, .. } = icub_mtb::parse(&frames[2]) else {
            panic!("{:?}", frames[2])
        };
        assert_eq!((raw[0], raw[1]), (240, 230));
        for frame in stop_commands(&host) {
            boards.obey(&frame);
        }
        assert!(boards.frames(&responses).is_empty());
    }

    #[test]
    fn fault_switches() {
        let faults = MtbFaults { drop_tails: true, error_nibble: Some(2), silence_after: Some(Duration::ZERO) };
        let mut boards = MtbBoards::new(1, 2, Duration::from_millis(40), faults);
        boards.obey(
            &icub_mtb::start_commands(&[HostBoard { address: 1, triangles: vec![0, 1] }], &BoardSettings::default())[2],
        );
        assert!(boards.frames(&[]).is_empty(), "silent after 0 s");
        boards.faults.silence_after = None;
        let frames = boards.frames(&[]);
        assert_eq!(frames.len(), 2, "heads only");
        boards.faults.drop_tails = false;
        let Message::Tail { error, .. } = icub_mtb::parse(&boards.frames(&[])[1]) else { panic!() };
        assert_eq!(error, 2);
    }
}
