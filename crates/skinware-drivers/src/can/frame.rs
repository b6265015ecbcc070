//! One classic CAN frame (standard or extended identifier, at most 8 data
//! bytes), the vocabulary every transport and protocol here shares. It
//! implements the ecosystem's `embedded_can::Frame`, so frames move to and from
//! any crate that speaks it (`socketcan` among them).

use embedded_can::{ExtendedId, Id, StandardId};

/// A classic CAN frame: a data frame or a remote (RTR) frame.
#[derive(Clone, Copy, PartialEq, Eq, Hash)]
pub struct CanFrame {
    id: Id,
    remote: bool,
    len: u8,
    data: [u8; 8],
}

impl CanFrame {
    /// A data frame with a standard (11-bit) identifier; `None` if `id` is
    /// above 0x7FF or `data` longer than 8 bytes.
    pub fn standard(id: u16, data: &[u8]) -> Option<CanFrame> {
        CanFrame::data(Id::Standard(StandardId::new(id)?), data)
    }

    /// A data frame with an extended (29-bit) identifier; `None` if `id` is
    /// above 0x1FFF_FFFF or `data` longer than 8 bytes.
    pub fn extended(id: u32, data: &[u8]) -> Option<CanFrame> {
        CanFrame::data(Id::Extended(ExtendedId::new(id)?), data)
    }

    /// A data frame; `None` if `data` is longer than 8 bytes.
    pub fn data(id: Id, data: &[u8]) -> Option<CanFrame> {
        let mut bytes = [0u8; 8];
        bytes.get_mut(..data.len())?.copy_from_slice(data);
        Some(CanFrame { id, remote: false, len: data.len() as u8, data: bytes })
    }

    /// A remote frame asking for `dlc` bytes; `None` if `dlc` is above 8.
    pub fn remote(id: Id, dlc: usize) -> Option<CanFrame> {
        (dlc <= 8).then_some(CanFrame { id, remote: true, len: dlc as u8, data: [0; 8] })
    }

    /// The identifier.
    pub fn id(&self) -> Id {
        self.id
    }

    /// The identifier as a number (11 or 29 bits).
    pub fn raw_id(&self) -> u32 {
        match self.id {
            Id::Standard(id) => u32::from(id.as_raw()),
            Id::Extended(id) => id.as_raw(),
        }
    }

    /// Whether the identifier is extended (29-bit).
    pub fn is_extended(&self) -> bool {
        matches!(self.id, Id::Extended(_))
    }

    /// Whether this is a remote (RTR) frame.
    pub fn is_remote(&self) -> bool {
        self.remote
    }

    /// The data length code: the bytes carried (or asked for, by a remote frame).
    pub fn dlc(&self) -> usize {
        usize::from(self.len)
    }

    /// The data bytes (empty for a remote frame).
    pub fn bytes(&self) -> &[u8] {
        if self.remote { &[] } else { &self.data[..self.dlc()] }
    }

    /// The `cansend` (and `candump` log) notation of the frame: `405#0A0B`,
    /// `12345678#`, `200#R2`.
    pub fn cansend_text(&self) -> String {
        let mut text =
            if self.is_extended() { format!("{:08X}#", self.raw_id()) } else { format!("{:03X}#", self.raw_id()) };
        if self.is_remote() {
            text.push('R');
            if self.dlc() > 0 {
                text.push(char::from(b'0' + self.dlc() as u8));
            }
        } else {
            for byte in self.bytes() {
                text.push_str(&format!("{byte:02X}"));
            }
        }
        text
    }
}

impl std::fmt::Debug for CanFrame {
    /// The `candump` notation: `123#DEADBEEF`, `12345678#01`, `123#R2`.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.cansend_text())
    }
}

impl embedded_can::Frame for CanFrame {
    fn new(id: impl Into<Id>, data: &[u8]) -> Option<Self> {
        CanFrame::data(id.into(), data)
    }

    fn new_remote(id: impl Into<Id>, dlc: usize) -> Option<Self> {
        CanFrame::remote(id.into(), dlc)
    }

    fn is_extended(&self) -> bool {
        CanFrame::is_extended(self)
    }

    fn is_remote_frame(&self) -> bool {
        self.remote
    }

    fn id(&self) -> Id {
        self.id
    }

    fn dlc(&self) -> usize {
        CanFrame::dlc(self)
    }

    fn data(&self) -> &[u8] {
        self.bytes()
    }
}

/// Any classic frame: standard or extended, data or remote, 0 to 8 bytes
/// (for the codecs' property tests).
#[cfg(test)]
pub(crate) fn any_frame() -> impl proptest::strategy::Strategy<Value = CanFrame> {
    use proptest::prelude::*;
    (any::<bool>(), any::<u32>(), any::<bool>(), proptest::collection::vec(any::<u8>(), 0..=8)).prop_map(
        |(extended, id, remote, data)| {
            let id = if extended {
                Id::Extended(ExtendedId::new(id & 0x1FFF_FFFF).unwrap())
            } else {
                Id::Standard(StandardId::new((id & 0x7FF) as u16).unwrap())
            };
            if remote { CanFrame::remote(id, data.len()).unwrap() } else { CanFrame::data(id, &data).unwrap() }
        },
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn identifiers_and_lengths_are_checked() {
        assert!(CanFrame::standard(0x7FF, &[0; 8]).is_some());
        assert!(CanFrame::standard(0x800, &[]).is_none());
        assert!(CanFrame::extended(0x1FFF_FFFF, &[]).is_some());
        assert!(CanFrame::extended(0x2000_0000, &[]).is_none());
        assert!(CanFrame::standard(1, &[0; 9]).is_none());
        assert!(CanFrame::remote(Id::Standard(StandardId::ZERO), 9).is_none());
    }

    #[test]
    fn embedded_can_sees_the_same_frame() {
        let frame = <CanFrame as embedded_can::Frame>::new(StandardId::new(0x405).unwrap(), &[1, 2, 3]).unwrap();
        assert_eq!((frame.raw_id(), frame.dlc(), frame.bytes()), (0x405, 3, &[1u8, 2, 3][..]));
        assert!(!embedded_can::Frame::is_extended(&frame));
        let remote = <CanFrame as embedded_can::Frame>::new_remote(ExtendedId::new(7).unwrap(), 4).unwrap();
        assert!(remote.is_remote() && remote.is_extended() && remote.bytes().is_empty() && remote.dlc() == 4);
    }
}
