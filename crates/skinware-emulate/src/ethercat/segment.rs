//! A line of tactile SubDevices on one EtherCAT port: frames go in as bytes,
//! pass every SubDevice in order, and come back (or not, by fault).

use std::num::NonZeroU64;
use std::time::{Duration, Instant};

use super::esc::TactileSubDevice;
use super::wire::{Command, Datagram, FrameError, FrameLayout, check_frame};

/// What the wire does wrong, on purpose.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SegmentFaults {
    /// Lose every Nth process-data frame (one with an LRD, LWR or LRW
    /// datagram, counting those offered while the link is up, from 1); the
    /// bring-up's frames are never lost. The frame is lost on its way out:
    /// no SubDevice sees it.
    pub drop_every_nth_frame: Option<NonZeroU64>,
    /// The cable is pulled: no frame reaches a SubDevice or comes back.
    pub link_down: bool,
    /// Answer every Nth process-data frame (one with an LRD, LWR or LRW
    /// datagram; counting from 1) `late_by` late: the frame goes round as
    /// usual, but the wire holds its answer back ([`Fate::Late`]).
    pub late_every_nth_frame: Option<NonZeroU64>,
    /// How late those answers are.
    pub late_by: Duration,
}

/// What became of a frame offered to the segment.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fate {
    /// It went round; the buffer holds the frame as it came back.
    Returned,
    /// Lost by the drop-every-Nth-process-data-frame fault.
    Dropped,
    /// The link is down.
    LinkDown,
    /// There is no SubDevice to send it back.
    NoSubDevice,
    /// It went round, as [`Fate::Returned`], but its answer is to go back
    /// this late (the late-answer fault).
    Late(Duration),
}

/// Counts of what the segment saw.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SegmentStats {
    /// Frames offered while the link was up.
    pub frames: u64,
    /// Frames that went round.
    pub returned: u64,
    /// Frames lost by the drop fault.
    pub dropped: u64,
    /// Frames refused as malformed.
    pub malformed: u64,
    /// Process-data frames (an LRD, LWR or LRW datagram in them) offered.
    pub process_data: u64,
    /// Answers held back by the late-answer fault.
    pub late: u64,
}

/// SubDevices in a line, position 0 nearest the MainDevice.
#[derive(Debug, Default)]
pub struct Segment {
    subdevices: Vec<TactileSubDevice>,
    faults: SegmentFaults,
    stats: SegmentStats,
}

impl Segment {
    /// A line of these SubDevices, in this order.
    pub fn new(subdevices: Vec<TactileSubDevice>) -> Segment {
        let mut segment = Segment { subdevices, faults: SegmentFaults::default(), stats: SegmentStats::default() };
        segment.wire_ports();
        segment
    }

    /// Every SubDevice but the last has a link on its port 1.
    fn wire_ports(&mut self) {
        let count = self.subdevices.len();
        for (position, subdevice) in self.subdevices.iter_mut().enumerate() {
            subdevice.set_downstream(position + 1 < count);
        }
    }

    /// The SubDevices, position 0 first.
    pub fn subdevices(&self) -> &[TactileSubDevice] {
        &self.subdevices
    }

    /// The SubDevice at `position`, to look at or to set its faults.
    pub fn subdevice_mut(&mut self, position: usize) -> Option<&mut TactileSubDevice> {
        self.subdevices.get_mut(position)
    }

    /// The wire's fault switches, to change at any time.
    pub fn faults_mut(&mut self) -> &mut SegmentFaults {
        &mut self.faults
    }

    /// What the segment saw so far.
    pub fn stats(&self) -> SegmentStats {
        self.stats
    }

    /// Sends `frame` (a whole Ethernet frame, as a MainDevice sends it) round
    /// the segment, changing it in place as the SubDevices do. A malformed
    /// frame is an error and, as on a real ring, does not come back; a frame
    /// is checked whole before any SubDevice acts on it.
    pub fn process(&mut self, frame: &mut [u8]) -> Result<Fate, FrameError> {
        if self.faults.link_down {
            return Ok(Fate::LinkDown);
        }
        self.stats.frames += 1;
        let layout = match check_frame(frame) {
            Ok(layout) => layout,
            Err(error) => {
                self.stats.malformed += 1;
                return Err(error);
            }
        };
        if self.subdevices.is_empty() {
            return Ok(Fate::NoSubDevice);
        }
        let process_data = is_process_data(frame, &layout);
        if process_data {
            self.stats.process_data += 1;
            // Only process data: losing the bring-up's frames would keep a
            // small N from ever reaching OP, which is not the fault asked for.
            if let Some(n) = self.faults.drop_every_nth_frame
                && self.stats.process_data.is_multiple_of(n.get())
            {
                self.stats.dropped += 1;
                return Ok(Fate::Dropped);
            }
        }
        let late = process_data
            && self.faults.late_every_nth_frame.is_some_and(|n| self.stats.process_data.is_multiple_of(n.get()));
        let now = Instant::now();
        let mut offset = layout.payload_start;
        while let Some(datagram) = Datagram::at(frame, offset, layout.payload_end) {
            for subdevice in &mut self.subdevices {
                subdevice.process(frame, &datagram, now);
            }
            if !datagram.more_follows {
                break;
            }
            offset = datagram.end;
        }
        // The first ESC sets the locally-administered bit of the source
        // address on the way back, which is how a MainDevice tells its own
        // frame from the answer.
        frame[6] |= 0x02;
        self.stats.returned += 1;
        if late {
            self.stats.late += 1;
            return Ok(Fate::Late(self.faults.late_by));
        }
        Ok(Fate::Returned)
    }
}

/// Whether the frame carries process data: a datagram addressed logically.
fn is_process_data(frame: &[u8], layout: &FrameLayout) -> bool {
    let mut offset = layout.payload_start;
    while let Some(datagram) = Datagram::at(frame, offset, layout.payload_end) {
        if matches!(datagram.command(frame), Command::Lrd | Command::Lwr | Command::Lrw) {
            return true;
        }
        if !datagram.more_follows {
            return false;
        }
        offset = datagram.end;
    }
    false
}

/// The segment as the EtherCAT driver's in-process bus: a frame that does
/// not come back (lost, link down, malformed) is `false`. So is a late one:
/// an in-process bus carries one frame at a time, so holding an answer back
/// would hold up every frame behind it; the frame's timeout is what the
/// MainDevice sees of a late answer in any case.
impl skinware_drivers::ethercat::FrameExchange for Segment {
    fn exchange(&mut self, frame: &mut Vec<u8>) -> bool {
        matches!(self.process(frame), Ok(Fate::Returned))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ethercat::esc::{AlState, TactileConfig};
    use crate::ethercat::wire::{Command, DatagramContents, FrameBuilder, datagrams};
    use proptest::prelude::*;

    fn segment(count: usize, taxels: usize) -> Segment {
        Segment::new(
            (0..count)
                .map(|k| {
                    TactileSubDevice::new(TactileConfig::new(taxels, k as u32 + 1), move |s: u64, t: &mut [u16]| {
                        t.iter_mut().enumerate().for_each(|(i, v)| *v = (s as u16) ^ (i as u16) ^ (k as u16 * 1000))
                    })
                    .unwrap()
                })
                .collect(),
        )
    }

    fn round(segment: &mut Segment, frame: FrameBuilder) -> Vec<DatagramContents> {
        let mut frame = frame.build();
        assert_eq!(segment.process(&mut frame).unwrap(), Fate::Returned);
        assert_eq!(frame[6], 0x12, "source address marked by the first ESC");
        datagrams(&frame).unwrap()
    }

    #[test]
    fn broadcast_read_counts_every_subdevice_and_ors_their_data() {
        let mut s = segment(3, 4);
        let out = round(&mut s, FrameBuilder::new().datagram(Command::Brd, 0, 0x0000_0000, &[0]));
        assert_eq!(out[0].working_counter, 3);
        assert_eq!(out[0].data, [0x11]);
        assert_eq!(out[0].address as u16, 3, "each SubDevice counted itself in the position");
        // Station addresses by position, then AL status ORed (INIT | PRE-OP).
        for position in 0..3u16 {
            let address = u32::from(0u16.wrapping_sub(position)) | 0x0010 << 16;
            let data = (0x1000 + position).to_le_bytes();
            assert_eq!(
                round(&mut s, FrameBuilder::new().datagram(Command::Apwr, 0, address, &data))[0].working_counter,
                1
            );
        }
        let to_preop = FrameBuilder::new().datagram(Command::Fpwr, 0, 0x0120_1001, &[2, 0]);
        assert_eq!(round(&mut s, to_preop)[0].working_counter, 1);
        assert_eq!(s.subdevices()[1].state(), AlState::PreOp);
        let out = round(&mut s, FrameBuilder::new().datagram(Command::Brd, 0, 0x0130_0000, &[0, 0]));
        assert_eq!((out[0].data[0], out[0].working_counter), (0x03, 3));
    }

    #[test]
    fn dl_status_reports_a_line() {
        let s = segment(3, 4);
        let links: Vec<u8> = s.subdevices().iter().map(|d| d.memory(0x0110, 1).unwrap()[0] & 0xF0).collect();
        assert_eq!(links, [0x30, 0x30, 0x10]);
    }

    #[test]
    fn faults_lose_process_data_frames_only() {
        let mut s = segment(1, 4);
        s.faults_mut().drop_every_nth_frame = NonZeroU64::new(3);
        let fates: Vec<Fate> = (0..6)
            .map(|_| {
                let mut frame = FrameBuilder::new().datagram(Command::Lrw, 0, 0, &[0; 8]).build();
                s.process(&mut frame).unwrap()
            })
            .collect();
        use Fate::*;
        assert_eq!(fates, [Returned, Returned, Dropped, Returned, Returned, Dropped]);
        // Register access (the bring-up's) is never lost, however many.
        for _ in 0..6 {
            let mut frame = FrameBuilder::new().datagram(Command::Brd, 0, 0, &[0]).build();
            assert_eq!(s.process(&mut frame).unwrap(), Returned);
        }
        s.faults_mut().link_down = true;
        let mut frame = FrameBuilder::new().datagram(Command::Brd, 0, 0, &[0]).build();
        assert_eq!(s.process(&mut frame).unwrap(), LinkDown);
        assert_eq!(s.stats().dropped, 2);
    }

    #[test]
    fn every_nth_process_data_frame_is_answered_late() {
        let mut s = segment(1, 4);
        s.faults_mut().late_every_nth_frame = NonZeroU64::new(2);
        s.faults_mut().late_by = Duration::from_millis(40);
        let mut fates = Vec::new();
        for _ in 0..3 {
            // A register read between two cycles is not process data.
            let mut frame = FrameBuilder::new().datagram(Command::Brd, 0, 0, &[0]).build();
            fates.push(s.process(&mut frame).unwrap());
            let mut frame = FrameBuilder::new().datagram(Command::Lrw, 0, 0, &[0; 8]).build();
            fates.push(s.process(&mut frame).unwrap());
        }
        use Fate::*;
        let late = Late(Duration::from_millis(40));
        assert_eq!(fates, [Returned, Returned, Returned, late, Returned, Returned]);
        assert_eq!((s.stats().process_data, s.stats().late, s.stats().returned), (3, 1, 6));
    }

    #[test]
    fn malformed_frames_are_errors() {
        let mut s = segment(1, 4);
        let good = FrameBuilder::new().datagram(Command::Brd, 0, 0, &[0, 0]).build();
        let mut short = good[..good.len() - 1].to_vec();
        assert!(matches!(s.process(&mut short), Err(FrameError::LengthBeyondFrame { .. })));
        let mut vlan = good.clone();
        vlan[12] = 0x81;
        assert!(matches!(s.process(&mut vlan), Err(FrameError::NotEtherCat { .. })));
        let mut bad_command = good.clone();
        bad_command[16] = 0x42;
        assert_eq!(s.process(&mut bad_command), Err(FrameError::UnknownCommand { index: 0, code: 0x42 }));
        let mut lying_length = good;
        lying_length[22] = 0xFF;
        assert!(matches!(s.process(&mut lying_length), Err(FrameError::DatagramTruncated { .. })));
        assert_eq!(s.stats().malformed, 4);
    }

    /// A valid frame of datagrams with arbitrary commands, addresses and data.
    fn arbitrary_frame() -> impl Strategy<Value = Vec<u8>> {
        prop::collection::vec((0u8..=0x0E, any::<u32>(), prop::collection::vec(any::<u8>(), 0..64)), 1..6).prop_map(
            |datagrams| {
                datagrams
                    .into_iter()
                    .fold(FrameBuilder::new(), |frame, (code, address, data)| {
                        frame.datagram(Command::from_code(code).unwrap(), 0, address, &data)
                    })
                    .build()
            },
        )
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(if cfg!(miri) { 8 } else { 2000 }))]

        /// Arbitrary bytes behind an EtherCAT Ethernet header (so that they
        /// reach the datagram parser) never panic the model.
        #[test]
        fn arbitrary_bytes_never_panic(
            mut bytes in prop::collection::vec(any::<u8>(), 0..1600),
            ethercat_header in any::<bool>(),
        ) {
            let mut s = segment(2, 8);
            if ethercat_header && bytes.len() >= 16 {
                bytes[12..14].copy_from_slice(&0x88A4u16.to_be_bytes());
                bytes[15] = (bytes[15] & 0x0F) | 0x10;
            }
            let _ = s.process(&mut bytes);
        }

        /// A mutated valid frame never panics, and either comes back the
        /// same length or is refused.
        #[test]
        fn mutated_frames_never_panic(
            frame in arbitrary_frame(),
            flips in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 0..8),
            cut in any::<prop::sample::Index>(),
        ) {
            let mut s = segment(3, 8);
            let mut frame = frame;
            for (at, value) in flips {
                let at = at.index(frame.len());
                frame[at] = value;
            }
            let keep = frame.len() - cut.index(frame.len()) / 4;
            frame.truncate(keep);
            let len = frame.len();
            if let Ok(Fate::Returned) = s.process(&mut frame) {
                prop_assert_eq!(frame.len(), len);
            }
        }

        /// Whatever a valid frame asks, every datagram's working counter
        /// grows by at most 3 per SubDevice (a read-write's read and write).
        #[test]
        fn working_counters_stay_sane(frame in arbitrary_frame(), subdevices in 1usize..4) {
            let mut s = segment(subdevices, 8);
            let mut frame = frame;
            prop_assert_eq!(s.process(&mut frame).unwrap(), Fate::Returned);
            for DatagramContents { command, working_counter: wkc, .. } in datagrams(&frame).unwrap() {
                let most = match command {
                    Command::Nop => 0,
                    // One SubDevice only sees position 0.
                    Command::Aprd | Command::Apwr => 1,
                    Command::Aprw => 3,
                    Command::Fprw | Command::Brw | Command::Lrw => 3 * subdevices,
                    _ => subdevices,
                };
                prop_assert!(usize::from(wkc) <= most, "{command:?} counted {wkc} with {subdevices} SubDevices");
            }
        }
    }
}
