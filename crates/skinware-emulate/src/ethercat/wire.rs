//! EtherCAT on the wire: the Ethernet II header, the EtherCAT header and the
//! datagrams (ETG1000.4 §5.3–5.4), read and written in place in a frame buffer.
//!
//! Everything here takes bytes from a bus: every length and offset is checked
//! before use, and a malformed frame is a [`FrameError`], never a panic.

/// The EtherType of EtherCAT frames.
pub const ETHERTYPE_ETHERCAT: u16 = 0x88A4;
/// Destination, source and EtherType.
pub const ETHERNET_HEADER_LEN: usize = 14;
/// The 16-bit EtherCAT header: 11 bits of length, 1 reserved, 4 bits of type.
pub const ETHERCAT_HEADER_LEN: usize = 2;
/// Command, index, address (4 bytes), length and flags (2), IRQ (2).
pub const DATAGRAM_HEADER_LEN: usize = 10;
/// The working counter that ends every datagram.
pub const WORKING_COUNTER_LEN: usize = 2;
/// EtherCAT header type 1: the frame carries DL PDUs (datagrams).
pub const ETHERCAT_TYPE_DATAGRAMS: u8 = 1;
/// Lengths in the EtherCAT and datagram headers are 11 bits wide.
pub const LENGTH_MASK: u16 = 0x07FF;
/// Datagram flag: another datagram follows this one in the frame.
const MORE_FOLLOWS: u16 = 1 << 15;
/// Datagram flag: the frame went round the ring once already.
const CIRCULATING: u16 = 1 << 14;

/// An EtherCAT command (ETG1000.4 Table 25).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Command {
    /// No operation: every SubDevice ignores the datagram.
    Nop,
    /// Auto-increment (position) read.
    Aprd,
    /// Auto-increment write.
    Apwr,
    /// Auto-increment read-write.
    Aprw,
    /// Configured-address read.
    Fprd,
    /// Configured-address write.
    Fpwr,
    /// Configured-address read-write.
    Fprw,
    /// Broadcast read.
    Brd,
    /// Broadcast write.
    Bwr,
    /// Broadcast read-write.
    Brw,
    /// Logical read.
    Lrd,
    /// Logical write.
    Lwr,
    /// Logical read-write.
    Lrw,
    /// Auto-increment read, multiple write.
    Armw,
    /// Configured-address read, multiple write.
    Frmw,
}

impl Command {
    /// The command for a code on the wire, if it is one.
    pub fn from_code(code: u8) -> Option<Command> {
        Some(match code {
            0x00 => Command::Nop,
            0x01 => Command::Aprd,
            0x02 => Command::Apwr,
            0x03 => Command::Aprw,
            0x04 => Command::Fprd,
            0x05 => Command::Fpwr,
            0x06 => Command::Fprw,
            0x07 => Command::Brd,
            0x08 => Command::Bwr,
            0x09 => Command::Brw,
            0x0A => Command::Lrd,
            0x0B => Command::Lwr,
            0x0C => Command::Lrw,
            0x0D => Command::Armw,
            0x0E => Command::Frmw,
            _ => return None,
        })
    }

    /// The code of this command on the wire.
    pub fn code(self) -> u8 {
        match self {
            Command::Nop => 0x00,
            Command::Aprd => 0x01,
            Command::Apwr => 0x02,
            Command::Aprw => 0x03,
            Command::Fprd => 0x04,
            Command::Fpwr => 0x05,
            Command::Fprw => 0x06,
            Command::Brd => 0x07,
            Command::Bwr => 0x08,
            Command::Brw => 0x09,
            Command::Lrd => 0x0A,
            Command::Lwr => 0x0B,
            Command::Lrw => 0x0C,
            Command::Armw => 0x0D,
            Command::Frmw => 0x0E,
        }
    }
}

/// Why a frame could not be processed. The segment then returns nothing, as
/// a real ring drops a frame it cannot parse (the MainDevice sees a timeout).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// Shorter than the Ethernet and EtherCAT headers.
    #[error("frame of {len} bytes is shorter than the Ethernet and EtherCAT headers")]
    TooShort {
        /// The frame's length.
        len: usize,
    },
    /// Another protocol (a VLAN tag is not supported either).
    #[error("EtherType {ethertype:#06x} is not EtherCAT (0x88a4)")]
    NotEtherCat {
        /// The EtherType found.
        ethertype: u16,
    },
    /// An EtherCAT frame that carries something other than datagrams
    /// (network variables, mailbox gateway).
    #[error("EtherCAT frame type {frame_type} is not supported (only 1, datagrams)")]
    UnsupportedType {
        /// The type found.
        frame_type: u8,
    },
    /// The EtherCAT header announces more bytes than the frame holds.
    #[error("EtherCAT header announces {declared} bytes of datagrams but the frame holds {available}")]
    LengthBeyondFrame {
        /// Bytes announced.
        declared: usize,
        /// Bytes present after the EtherCAT header.
        available: usize,
    },
    /// A datagram's header, data or working counter runs past the announced length.
    #[error("datagram {index} (at byte {offset}) runs past the end of the EtherCAT payload")]
    DatagramTruncated {
        /// Position of the datagram in the frame, from 0.
        index: usize,
        /// Its offset in the EtherCAT payload.
        offset: usize,
    },
    /// A command code that EtherCAT does not define.
    #[error("datagram {index} has unknown command code {code:#04x}")]
    UnknownCommand {
        /// Position of the datagram in the frame.
        index: usize,
        /// The code found.
        code: u8,
    },
    /// The EtherCAT header announces no datagram at all.
    #[error("EtherCAT frame carries no datagram")]
    Empty,
}

/// Where the datagrams of a frame are: `payload` is the range of the frame
/// announced by the EtherCAT header.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameLayout {
    /// Offset of the first datagram in the frame.
    pub payload_start: usize,
    /// Offset just past the last announced byte.
    pub payload_end: usize,
}

/// Checks the Ethernet and EtherCAT headers and that every datagram fits.
pub fn check_frame(frame: &[u8]) -> Result<FrameLayout, FrameError> {
    let headers = ETHERNET_HEADER_LEN + ETHERCAT_HEADER_LEN;
    if frame.len() < headers {
        return Err(FrameError::TooShort { len: frame.len() });
    }
    let ethertype = u16::from_be_bytes([frame[12], frame[13]]);
    if ethertype != ETHERTYPE_ETHERCAT {
        return Err(FrameError::NotEtherCat { ethertype });
    }
    let header = u16::from_le_bytes([frame[14], frame[15]]);
    let frame_type = (header >> 12) as u8;
    if frame_type != ETHERCAT_TYPE_DATAGRAMS {
        return Err(FrameError::UnsupportedType { frame_type });
    }
    let declared = usize::from(header & LENGTH_MASK);
    let available = frame.len() - headers;
    if declared > available {
        return Err(FrameError::LengthBeyondFrame { declared, available });
    }
    if declared == 0 {
        return Err(FrameError::Empty);
    }
    let layout = FrameLayout { payload_start: headers, payload_end: headers + declared };
    let mut offset = layout.payload_start;
    let mut index = 0;
    loop {
        let datagram = Datagram::at(frame, offset, layout.payload_end)
            .ok_or(FrameError::DatagramTruncated { index, offset: offset - layout.payload_start })?;
        if Command::from_code(frame[offset]).is_none() {
            return Err(FrameError::UnknownCommand { index, code: frame[offset] });
        }
        if !datagram.more_follows {
            return Ok(layout);
        }
        offset = datagram.end;
        index += 1;
    }
}

/// One datagram's position in a frame, its length and flags, already checked
/// to fit inside the EtherCAT payload.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Datagram {
    /// Offset of the datagram header in the frame.
    pub start: usize,
    /// Length of the data.
    pub data_len: usize,
    /// Whether another datagram follows.
    pub more_follows: bool,
    /// Offset just past the working counter.
    pub end: usize,
}

impl Datagram {
    /// The datagram whose header starts at `start`, if it fits before `limit`.
    pub fn at(frame: &[u8], start: usize, limit: usize) -> Option<Datagram> {
        let header_end = start.checked_add(DATAGRAM_HEADER_LEN)?;
        if header_end > limit || limit > frame.len() {
            return None;
        }
        let flags = u16::from_le_bytes([frame[start + 6], frame[start + 7]]);
        let data_len = usize::from(flags & LENGTH_MASK);
        let end = header_end + data_len + WORKING_COUNTER_LEN;
        if end > limit {
            return None;
        }
        Some(Datagram { start, data_len, more_follows: flags & MORE_FOLLOWS != 0, end })
    }

    /// The command (checked by [`check_frame`]; `Nop` for an unknown code).
    pub fn command(&self, frame: &[u8]) -> Command {
        Command::from_code(frame[self.start]).unwrap_or(Command::Nop)
    }

    /// The 32-bit address field: position or station address in the low
    /// half and register offset in the high half, or a logical address.
    pub fn address(&self, frame: &[u8]) -> u32 {
        let a = &frame[self.start + 2..self.start + 6];
        u32::from_le_bytes([a[0], a[1], a[2], a[3]])
    }

    /// Rewrites the address field (auto-increment and broadcast commands
    /// count the SubDevices they pass in its low half).
    pub fn set_address(&self, frame: &mut [u8], address: u32) {
        frame[self.start + 2..self.start + 6].copy_from_slice(&address.to_le_bytes());
    }

    /// Marks the datagram as having circulated (a frame that reached the end
    /// of an open ring and came back through the first port).
    pub fn set_circulating(&self, frame: &mut [u8]) {
        let flags = u16::from_le_bytes([frame[self.start + 6], frame[self.start + 7]]) | CIRCULATING;
        frame[self.start + 6..self.start + 8].copy_from_slice(&flags.to_le_bytes());
    }

    /// The range of the data in the frame.
    pub fn data_range(&self) -> std::ops::Range<usize> {
        let data_start = self.start + DATAGRAM_HEADER_LEN;
        data_start..data_start + self.data_len
    }

    /// The working counter.
    pub fn working_counter(&self, frame: &[u8]) -> u16 {
        u16::from_le_bytes([frame[self.end - 2], frame[self.end - 1]])
    }

    /// Rewrites the working counter.
    pub fn set_working_counter(&self, frame: &mut [u8], wkc: u16) {
        frame[self.end - 2..self.end].copy_from_slice(&wkc.to_le_bytes());
    }
}

/// Builds a frame of datagrams, as a MainDevice would send it: used by the
/// model's own tests and by anything that wants to talk to a segment without
/// a MainDevice.
#[derive(Clone, Debug)]
pub struct FrameBuilder {
    frame: Vec<u8>,
    last_datagram: Option<usize>,
}

impl Default for FrameBuilder {
    fn default() -> Self {
        FrameBuilder::new()
    }
}

impl FrameBuilder {
    /// An empty frame from the MAC address ethercrab uses, to broadcast.
    pub fn new() -> FrameBuilder {
        let mut frame = Vec::with_capacity(1514);
        frame.extend_from_slice(&[0xFF; 6]);
        frame.extend_from_slice(&[0x10; 6]);
        frame.extend_from_slice(&ETHERTYPE_ETHERCAT.to_be_bytes());
        frame.extend_from_slice(&[0, 0]);
        FrameBuilder { frame, last_datagram: None }
    }

    /// Appends a datagram with `data` (its length is the datagram's length)
    /// and a working counter of 0; `index` is the MainDevice's tag.
    pub fn datagram(mut self, command: Command, index: u8, address: u32, data: &[u8]) -> FrameBuilder {
        let data_len = data.len().min(usize::from(LENGTH_MASK));
        if let Some(previous) = self.last_datagram {
            self.frame[previous + 7] |= (MORE_FOLLOWS >> 8) as u8;
        }
        self.last_datagram = Some(self.frame.len());
        self.frame.push(command.code());
        self.frame.push(index);
        self.frame.extend_from_slice(&address.to_le_bytes());
        self.frame.extend_from_slice(&(data_len as u16).to_le_bytes());
        self.frame.extend_from_slice(&[0, 0]);
        self.frame.extend_from_slice(&data[..data_len]);
        self.frame.extend_from_slice(&[0, 0]);
        self
    }

    /// The frame, with the EtherCAT header's length filled in.
    pub fn build(mut self) -> Vec<u8> {
        let payload = (self.frame.len() - ETHERNET_HEADER_LEN - ETHERCAT_HEADER_LEN) as u16 & LENGTH_MASK;
        let header = payload | (u16::from(ETHERCAT_TYPE_DATAGRAMS) << 12);
        self.frame[14..16].copy_from_slice(&header.to_le_bytes());
        self.frame
    }
}

/// One datagram of a frame, copied out.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DatagramContents {
    /// The command.
    pub command: Command,
    /// The address field (position or station address and register, or
    /// logical address).
    pub address: u32,
    /// The data.
    pub data: Vec<u8>,
    /// The working counter.
    pub working_counter: u16,
}

/// Reads the datagrams of a processed frame back, or `None` if the frame is
/// malformed.
pub fn datagrams(frame: &[u8]) -> Option<Vec<DatagramContents>> {
    let layout = check_frame(frame).ok()?;
    let mut out = Vec::new();
    let mut offset = layout.payload_start;
    loop {
        let datagram = Datagram::at(frame, offset, layout.payload_end)?;
        out.push(DatagramContents {
            command: datagram.command(frame),
            address: datagram.address(frame),
            data: frame[datagram.data_range()].to_vec(),
            working_counter: datagram.working_counter(frame),
        });
        if !datagram.more_follows {
            return Some(out);
        }
        offset = datagram.end;
    }
}
