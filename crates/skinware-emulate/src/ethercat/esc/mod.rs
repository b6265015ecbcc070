//! One tactile SubDevice: an ET1100-class EtherCAT SubDevice Controller (ESC)
//! with its register space, SII EEPROM, FMMUs and SyncManagers, and the
//! segment firmware on its PDI side running the AL state machine.
//!
//! What is modelled, and what is not:
//! * 8 FMMUs, 8 SyncManagers, 8 KiB of process memory at 0x1000;
//! * no distributed clocks: the feature register says so and the DC block
//!   (0x0900–0x09FF) does not answer, so accesses to it leave the working
//!   counter alone (ethercrab counts DC SubDevices that way);
//! * FMMUs map whole bytes (the feature register says byte-oriented);
//! * SyncManagers in buffered mode hand the MainDevice a whole sample: the
//!   inputs are sampled when a read starts at SM3's first byte, the outputs
//!   taken when a write reaches SM2's last byte; buffered SyncManagers answer
//!   in SAFE-OP and OP only (the firmware keeps them deactivated before);
//! * no mailbox (the PDO map is fixed, read from the SII); a SyncManager set
//!   to mailbox mode does not answer;
//! * SII accesses complete at once (never busy); the alias register is
//!   loaded from the SII at power-up and on a reload command;
//! * the SyncManager watchdog does not run on its own: the "leave OP" fault
//!   switch plays its part (AL status code 0x001B), deterministically.

use std::time::{Duration, Instant};

use super::sii::{self, Identity};
use super::tactile::{
    EMULATED_PRODUCT_CODE, EMULATED_VENDOR_ID, Firmware, INPUTS_ADDRESS, INPUTS_HEADER_BYTES, MAX_TAXELS,
    OUTPUTS_ADDRESS, OUTPUTS_BYTES, TaxelSource,
};
use super::wire::{Command, Datagram};

// The memory the MainDevice reads and writes (registers, FMMUs mapping
// process memory through SyncManagers), and the firmware's side of it (the AL
// state machine and the SII interface): methods of `TactileSubDevice` in
// their own files.
mod al;
mod memory;

/// Bytes of process memory above the registers.
const PROCESS_MEMORY_BYTES: usize = 8 * 1024;
/// Registers end and process memory starts here.
const PROCESS_MEMORY_START: u32 = 0x1000;
const FMMUS: usize = 8;
const SYNC_MANAGERS: usize = 8;
const FMMU_BASE: u16 = 0x0600;
const SYNC_MANAGER_BASE: u16 = 0x0800;

// Registers (ETG1000.4 Table 31 onwards).
const REG_TYPE: usize = 0x0000;
const REG_REVISION: usize = 0x0001;
const REG_BUILD: usize = 0x0002;
const REG_FMMU_COUNT: usize = 0x0004;
const REG_SYNC_MANAGER_COUNT: usize = 0x0005;
const REG_RAM_SIZE: usize = 0x0006;
const REG_PORT_DESCRIPTOR: usize = 0x0007;
const REG_FEATURES: usize = 0x0008;
const REG_STATION_ADDRESS: usize = 0x0010;
const REG_STATION_ALIAS: usize = 0x0012;
const REG_DL_STATUS: usize = 0x0110;
const REG_AL_CONTROL: usize = 0x0120;
const REG_AL_STATUS: usize = 0x0130;
const REG_AL_STATUS_CODE: usize = 0x0134;
const REG_SII_CONFIG: usize = 0x0500;
const REG_SII_CONTROL: usize = 0x0502;
const REG_SII_ADDRESS: usize = 0x0504;
const REG_SII_DATA: usize = 0x0508;
const SII_READ_BYTES: usize = 8;

// SII control/status bits (ETG1000.4 Table 48).
const SII_WRITE_ENABLE: u16 = 0x0001;
const SII_READ_8_BYTES: u16 = 0x0040;
const SII_ADDRESS_16_BIT: u16 = 0x0080;
const SII_COMMAND_MASK: u16 = 0x0700;
const SII_COMMAND_READ: u16 = 0x0100;
const SII_COMMAND_WRITE: u16 = 0x0200;
const SII_COMMAND_RELOAD: u16 = 0x0400;
const SII_CHECKSUM_ERROR: u16 = 0x0800;
const SII_COMMAND_ERROR: u16 = 0x2000;
const SII_WRITE_ERROR: u16 = 0x4000;

/// AL status codes (ETG1000.6 Table 11) the segment reports.
pub mod al_status_code {
    /// No error.
    pub const NO_ERROR: u16 = 0x0000;
    /// The requested transition skips a state or goes nowhere allowed.
    pub const INVALID_STATE_CHANGE: u16 = 0x0011;
    /// The requested state is not an EtherCAT state.
    pub const UNKNOWN_STATE: u16 = 0x0012;
    /// The segment has no bootloader.
    pub const BOOTSTRAP_NOT_SUPPORTED: u16 = 0x0013;
    /// The SyncManager watchdog expired: the MainDevice stopped sending outputs.
    pub const SYNC_MANAGER_WATCHDOG: u16 = 0x001B;
    /// SM2 (outputs) is not configured as the SII describes.
    pub const INVALID_OUTPUT_CONFIGURATION: u16 = 0x001D;
    /// SM3 (inputs) is not configured as the SII describes.
    pub const INVALID_INPUT_CONFIGURATION: u16 = 0x001E;
}

/// An EtherCAT application-layer state (the low nibble of AL status).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum AlState {
    /// INIT.
    Init,
    /// PRE-OP.
    PreOp,
    /// SAFE-OP: inputs valid, outputs not applied.
    SafeOp,
    /// OP.
    Op,
}

impl AlState {
    /// The state's code in AL control and AL status.
    pub fn code(self) -> u8 {
        match self {
            AlState::Init => 1,
            AlState::PreOp => 2,
            AlState::SafeOp => 4,
            AlState::Op => 8,
        }
    }
}

/// When a SubDevice with the "leave OP" fault drops to SAFE-OP with an error.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LeaveOp {
    /// After this many process-data cycles in OP (datagrams that read its
    /// inputs): deterministic, for tests.
    AfterCycles(u64),
    /// After this long in OP: for an emulator on a real interface.
    AfterTime(Duration),
}

/// What one SubDevice does wrong, on purpose.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SubDeviceFaults {
    /// Leave OP (to SAFE-OP, error flag, code 0x001B, the watchdog's) as
    /// this says; once per entry into OP.
    pub leave_op: Option<LeaveOp>,
    /// Exchange process data but leave the working counter of logical
    /// datagrams alone, as a SubDevice whose SyncManagers are not serviced:
    /// the MainDevice sees a working counter short by this SubDevice's share.
    pub wrong_working_counter: bool,
}

/// What a tactile segment is: identity, taxels, names.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TactileConfig {
    /// Identity in the SII.
    pub identity: Identity,
    /// Station alias in the SII (0: none).
    pub alias: u16,
    /// Taxels, 1..=[`MAX_TAXELS`].
    pub taxels: usize,
    /// Order code: the name ethercrab gives the SubDevice.
    pub order: String,
    /// Longer device name.
    pub name: String,
}

impl TactileConfig {
    /// A segment of `taxels` taxels with the emulator's vendor and product
    /// and serial number `serial`.
    pub fn new(taxels: usize, serial: u32) -> TactileConfig {
        TactileConfig {
            identity: Identity {
                vendor_id: EMULATED_VENDOR_ID,
                product_code: EMULATED_PRODUCT_CODE,
                revision: 1,
                serial,
            },
            alias: 0,
            taxels,
            order: format!("SKIN-T{taxels}"),
            name: format!("Skinware emulated tactile segment, {taxels} taxels"),
        }
    }
}

/// A configuration the model cannot build.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum ConfigError {
    /// Taxels outside 1..=MAX_TAXELS.
    #[error("a tactile segment has 1 to {max} taxels, not {taxels}: its inputs must fit the ESC's process memory")]
    Taxels {
        /// Taxels asked for.
        taxels: usize,
        /// The most a segment carries.
        max: usize,
    },
}

/// Kinds of access to one byte of ESC memory from the EtherCAT side.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Access {
    Read,
    Write,
}

/// A tactile SubDevice: ESC and firmware.
#[derive(Debug)]
pub struct TactileSubDevice {
    config: TactileConfig,
    memory: Vec<u8>,
    sii: Vec<u8>,
    sii_checksum_ok: bool,
    firmware: Firmware,
    state: AlState,
    error: Option<u16>,
    faults: SubDeviceFaults,
    op_cycles: u64,
    op_since: Option<Instant>,
    downstream: bool,
}

impl TactileSubDevice {
    /// A segment at power-up (INIT), whose taxels read what `source` says.
    pub fn new(config: TactileConfig, source: impl TaxelSource + 'static) -> Result<TactileSubDevice, ConfigError> {
        if config.taxels == 0 || config.taxels > MAX_TAXELS {
            return Err(ConfigError::Taxels { taxels: config.taxels, max: MAX_TAXELS });
        }
        let image = sii::tactile_image(config.identity, config.alias, config.taxels, &config.order, &config.name);
        Ok(TactileSubDevice::with_sii(config, image, Box::new(source)))
    }

    /// A segment with an SII image of the caller's, for tests of what a
    /// MainDevice does with a wrong or corrupt one.
    pub fn with_sii(config: TactileConfig, image: Vec<u8>, source: Box<dyn TaxelSource>) -> TactileSubDevice {
        let taxels = config.taxels.min(MAX_TAXELS);
        let mut device = TactileSubDevice {
            memory: vec![0; PROCESS_MEMORY_START as usize + PROCESS_MEMORY_BYTES],
            sii_checksum_ok: false,
            firmware: Firmware::new(taxels, source),
            state: AlState::Init,
            error: None,
            faults: SubDeviceFaults::default(),
            op_cycles: 0,
            op_since: None,
            downstream: false,
            sii: image,
            config,
        };
        device.power_up();
        device
    }

    fn power_up(&mut self) {
        let m = &mut self.memory;
        m[REG_TYPE] = 0x11;
        m[REG_REVISION] = 0x00;
        m[REG_BUILD..REG_BUILD + 2].copy_from_slice(&0x0002u16.to_le_bytes());
        m[REG_FMMU_COUNT] = FMMUS as u8;
        m[REG_SYNC_MANAGER_COUNT] = SYNC_MANAGERS as u8;
        m[REG_RAM_SIZE] = (PROCESS_MEMORY_BYTES / 1024) as u8;
        // Ports 0 and 1 are MII (0b11), ports 2 and 3 not implemented.
        m[REG_PORT_DESCRIPTOR] = 0x0F;
        // Bit 0: FMMUs are byte-oriented. No DC (bit 2 clear).
        m[REG_FEATURES..REG_FEATURES + 2].copy_from_slice(&0x0001u16.to_le_bytes());
        self.sii_checksum_ok = self.sii.len() >= 16
            && u16::from(sii::checksum(&self.sii[..14])) == u16::from_le_bytes([self.sii[14], self.sii[15]]);
        self.reload_sii();
        self.store_sii_status(SII_READ_8_BYTES | SII_ADDRESS_16_BIT);
        self.store_al_status();
        self.store_dl_status();
    }

    /// Loads what an ESC takes from its SII at power-up: the alias.
    fn reload_sii(&mut self) {
        let alias = if self.sii_checksum_ok { [self.sii[8], self.sii[9]] } else { [0, 0] };
        self.memory[REG_STATION_ALIAS..REG_STATION_ALIAS + 2].copy_from_slice(&alias);
    }

    /// Tells the SubDevice whether another follows it on the ring (its port
    /// 1 has a link), which its DL status reports.
    pub(crate) fn set_downstream(&mut self, downstream: bool) {
        self.downstream = downstream;
        self.store_dl_status();
    }

    fn store_dl_status(&mut self) {
        // PDI operational (the SII loaded), watchdog fine, link and signal on
        // port 0; port 1 likewise if a SubDevice follows, else closed
        // (loop-back); ports 2 and 3 closed.
        let mut status: u16 = 0x0001 | 0x0002 | 1 << 4 | 1 << 9;
        if !self.sii_checksum_ok {
            status &= !0x0001;
        }
        if self.downstream {
            status |= 1 << 5 | 1 << 11;
        } else {
            status |= 1 << 10;
        }
        status |= 1 << 12 | 1 << 14;
        self.memory[REG_DL_STATUS..REG_DL_STATUS + 2].copy_from_slice(&status.to_le_bytes());
    }

    fn store_al_status(&mut self) {
        let status = self.state.code() | if self.error.is_some() { 0x10 } else { 0 };
        self.memory[REG_AL_STATUS..REG_AL_STATUS + 2].copy_from_slice(&u16::from(status).to_le_bytes());
        let code = self.error.unwrap_or(al_status_code::NO_ERROR);
        self.memory[REG_AL_STATUS_CODE..REG_AL_STATUS_CODE + 2].copy_from_slice(&code.to_le_bytes());
    }

    fn store_sii_status(&mut self, status: u16) {
        self.memory[REG_SII_CONTROL..REG_SII_CONTROL + 2].copy_from_slice(&status.to_le_bytes());
    }

    /// The configuration it was built from.
    pub fn config(&self) -> &TactileConfig {
        &self.config
    }

    /// Its AL state.
    pub fn state(&self) -> AlState {
        self.state
    }

    /// The AL status code of its error, if the error flag is set.
    pub fn error(&self) -> Option<u16> {
        self.error
    }

    /// The station address the MainDevice gave it.
    pub fn station_address(&self) -> u16 {
        u16::from_le_bytes([self.memory[REG_STATION_ADDRESS], self.memory[REG_STATION_ADDRESS + 1]])
    }

    /// Samples taken (the counter's full value).
    pub fn samples(&self) -> u64 {
        self.firmware.samples()
    }

    /// The command and config words last taken in OP.
    pub fn command_and_config(&self) -> (u16, u16) {
        self.firmware.command_and_config()
    }

    /// The SII image (changed by SII writes from the MainDevice).
    pub fn sii(&self) -> &[u8] {
        &self.sii
    }

    /// `len` bytes of its memory (registers and process memory) from
    /// `address`, as a debugger on the PDI side would see them.
    pub fn memory(&self, address: u16, len: usize) -> Option<&[u8]> {
        self.memory.get(usize::from(address)..usize::from(address).checked_add(len)?)
    }

    /// Its fault switches, to change at any time.
    pub fn faults_mut(&mut self) -> &mut SubDeviceFaults {
        &mut self.faults
    }

    /// Processes one datagram passing through it on the ring: addressing,
    /// access, working counter.
    pub(crate) fn process(&mut self, frame: &mut [u8], datagram: &Datagram, now: Instant) {
        self.check_leave_op_time(now);
        let command = datagram.command(frame);
        let address = datagram.address(frame);
        let position = address as u16;
        let offset = (address >> 16) as u16;
        let data = datagram.data_range();
        let increment: u16 = match command {
            Command::Nop => 0,
            Command::Aprd | Command::Apwr | Command::Aprw | Command::Armw => {
                // Every SubDevice counts itself in the position; the one that
                // sees 0 is addressed.
                datagram.set_address(frame, u32::from(position.wrapping_add(1)) | u32::from(offset) << 16);
                match (command, position == 0) {
                    (Command::Armw, false) => self.physical(Command::Apwr, offset, &mut frame[data], false),
                    (Command::Armw, true) => self.physical(Command::Aprd, offset, &mut frame[data], false),
                    (_, true) => self.physical(command, offset, &mut frame[data], false),
                    (_, false) => 0,
                }
            }
            Command::Fprd | Command::Fpwr | Command::Fprw | Command::Frmw => {
                let addressed = position == self.station_address();
                match (command, addressed) {
                    (Command::Frmw, false) => self.physical(Command::Fpwr, offset, &mut frame[data], false),
                    (Command::Frmw, true) => self.physical(Command::Fprd, offset, &mut frame[data], false),
                    (_, true) => self.physical(command, offset, &mut frame[data], false),
                    (_, false) => 0,
                }
            }
            Command::Brd | Command::Bwr | Command::Brw => {
                datagram.set_address(frame, u32::from(position.wrapping_add(1)) | u32::from(offset) << 16);
                self.physical(command, offset, &mut frame[data], true)
            }
            Command::Lrd | Command::Lwr | Command::Lrw => {
                let increment = self.logical(command, address, &mut frame[data]);
                if self.faults.wrong_working_counter { 0 } else { increment }
            }
        };
        let wkc = datagram.working_counter(frame).wrapping_add(increment);
        datagram.set_working_counter(frame, wkc);
    }

    /// A register or memory access by physical address; returns the working
    /// counter increment. Broadcast reads OR their data into the datagram.
    fn physical(&mut self, command: Command, offset: u16, data: &mut [u8], broadcast: bool) -> u16 {
        let start = u32::from(offset);
        match command {
            Command::Aprd | Command::Fprd | Command::Brd => u16::from(self.read(start, data, broadcast)),
            Command::Apwr | Command::Fpwr | Command::Bwr => u16::from(self.write(start, data)),
            Command::Aprw | Command::Fprw | Command::Brw => {
                // Data in is written; data out is what the memory held.
                let incoming = data.to_vec();
                let read = self.read(start, data, broadcast);
                let written = self.write(start, &incoming);
                u16::from(read) + 2 * u16::from(written)
            }
            _ => 0,
        }
    }

    /// A logical access through the FMMUs; returns the working counter
    /// increment: +1 if anything was read, +1 (LWR) or +2 (LRW) if anything
    /// was written.
    fn logical(&mut self, command: Command, address: u32, data: &mut [u8]) -> u16 {
        let reads = matches!(command, Command::Lrd | Command::Lrw);
        let writes = matches!(command, Command::Lwr | Command::Lrw);
        let datagram_start = u64::from(address);
        let datagram_end = datagram_start + data.len() as u64;
        // What each FMMU maps of this datagram: (where in the data, where in
        // memory, read or write).
        let mut accesses = [((0usize, 0usize), 0u32, Access::Read); 2 * FMMUS];
        let mut count = 0;
        for fmmu in 0..FMMUS {
            let base = usize::from(FMMU_BASE) + fmmu * 16;
            let register = &self.memory[base..base + 16];
            if register[12] & 0x01 == 0 {
                continue;
            }
            let logical_start = u64::from(u32::from_le_bytes([register[0], register[1], register[2], register[3]]));
            let length = u64::from(u16::from_le_bytes([register[4], register[5]]));
            let physical_start = u64::from(u16::from_le_bytes([register[8], register[9]]));
            let from = datagram_start.max(logical_start);
            let to = datagram_end.min(logical_start + length);
            if from >= to {
                continue;
            }
            let in_data = ((from - datagram_start) as usize, (to - datagram_start) as usize);
            let physical = (physical_start + (from - logical_start)) as u32;
            if reads && register[11] & 0x01 != 0 {
                accesses[count] = (in_data, physical, Access::Read);
                count += 1;
            }
            if writes && register[11] & 0x02 != 0 {
                accesses[count] = (in_data, physical, Access::Write);
                count += 1;
            }
        }
        // A real ESC handles the datagram byte by byte as it passes: what is
        // mapped first is done first, so inputs mapped before the outputs
        // (as a MainDevice's process image has them) are read out before the
        // outputs are written, and a new command shows in the next cycle's
        // inputs, not this one's. At one byte, the read comes first.
        let accesses = &mut accesses[..count];
        accesses.sort_unstable_by_key(|&((start, _), _, access)| (start, access == Access::Write));
        // Outputs written are the data as it came in, not as reads left it.
        let incoming = if writes && reads { data.to_vec() } else { Vec::new() };
        let mut read_any = false;
        let mut wrote_any = false;
        for &((start, end), physical, access) in accesses.iter() {
            match access {
                Access::Read => read_any |= self.read(physical, &mut data[start..end], false),
                Access::Write => {
                    let source = if incoming.is_empty() { &data[start..end] } else { &incoming[start..end] };
                    wrote_any |= self.write(physical, source);
                }
            }
        }
        let inputs_read = read_any;
        if inputs_read && self.state == AlState::Op {
            self.op_cycles += 1;
            if let Some(LeaveOp::AfterCycles(cycles)) = self.faults.leave_op
                && self.op_cycles >= cycles
            {
                self.drop_out_of_op();
            }
        }
        let write_weight = if command == Command::Lrw { 2 } else { 1 };
        u16::from(read_any) + write_weight * u16::from(wrote_any)
    }

    fn check_leave_op_time(&mut self, now: Instant) {
        if let (Some(LeaveOp::AfterTime(after)), Some(since)) = (self.faults.leave_op, self.op_since)
            && self.state == AlState::Op
            && now.saturating_duration_since(since) >= after
        {
            self.drop_out_of_op();
        }
    }

    /// What the firmware does when its SyncManager watchdog expires.
    fn drop_out_of_op(&mut self) {
        self.state = AlState::SafeOp;
        self.error = Some(al_status_code::SYNC_MANAGER_WATCHDOG);
        self.op_since = None;
        self.store_al_status();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::ethercat::wire::{DatagramContents, FrameBuilder, check_frame, datagrams};

    fn device(taxels: usize) -> TactileSubDevice {
        TactileSubDevice::new(TactileConfig::new(taxels, 1), |sample: u64, taxels: &mut [u16]| {
            for (k, t) in taxels.iter_mut().enumerate() {
                *t = (sample as u16).wrapping_mul(7).wrapping_add(k as u16);
            }
        })
        .unwrap()
    }

    /// Runs one frame through one device and returns its datagrams.
    fn run(device: &mut TactileSubDevice, frame: FrameBuilder) -> Vec<DatagramContents> {
        let mut frame = frame.build();
        let layout = check_frame(&frame).unwrap();
        let mut offset = layout.payload_start;
        loop {
            let datagram = Datagram::at(&frame, offset, layout.payload_end).unwrap();
            device.process(&mut frame, &datagram, Instant::now());
            if !datagram.more_follows {
                break;
            }
            offset = datagram.end;
        }
        datagrams(&frame).unwrap()
    }

    fn fpwr(device: &mut TactileSubDevice, register: u16, data: &[u8]) -> u16 {
        let address = u32::from(device.station_address()) | u32::from(register) << 16;
        run(device, FrameBuilder::new().datagram(Command::Fpwr, 0, address, data))[0].working_counter
    }

    #[test]
    fn auto_increment_counts_position_and_addresses_only_position_zero() {
        let mut d = device(4);
        // APWR to position 1 (0xFFFF): not this device; the position counts on.
        let out = run(&mut d, FrameBuilder::new().datagram(Command::Apwr, 0, 0x0010_FFFF, &[0x34, 0x12]));
        assert_eq!(out[0].address as u16, 0x0000);
        assert_eq!(out[0].working_counter, 0);
        assert_eq!(d.station_address(), 0);
        let out = run(&mut d, FrameBuilder::new().datagram(Command::Apwr, 0, 0x0010_0000, &[0x34, 0x12]));
        assert_eq!((out[0].address as u16, out[0].working_counter), (1, 1));
        assert_eq!(d.station_address(), 0x1234);
    }

    #[test]
    fn read_write_counts_three_and_returns_the_old_value() {
        let mut d = device(4);
        fpwr(&mut d, 0x0010, &[0x01, 0x10]);
        let out = run(&mut d, FrameBuilder::new().datagram(Command::Fprw, 0, 0x0400_1001, &[0xAA, 0x00]));
        assert_eq!(out[0].data, [0, 0]);
        assert_eq!(out[0].working_counter, 3);
        assert_eq!(d.memory(0x0400, 2).unwrap(), [0xAA, 0]);
        // A read-only register is still counted, but keeps its value.
        let out = run(&mut d, FrameBuilder::new().datagram(Command::Fprw, 0, 0x0000_1001, &[0xFF]));
        assert_eq!((out[0].data.as_slice(), out[0].working_counter), (&[0x11][..], 3));
        assert_eq!(d.memory(0, 1).unwrap(), [0x11]);
    }

    #[test]
    fn no_dc_registers_means_no_working_counter() {
        let mut d = device(4);
        let out = run(&mut d, FrameBuilder::new().datagram(Command::Bwr, 0, 0x0900_0000, &[0; 4]));
        assert_eq!(out[0].working_counter, 0);
        let out = run(&mut d, FrameBuilder::new().datagram(Command::Brd, 0, 0x0008_0000, &[0; 2]));
        assert_eq!(out[0].data[0] & 0x04, 0, "the feature register says: no DC");
    }

    #[test]
    fn al_state_machine_refuses_skipped_states_with_a_code() {
        let mut d = device(4);
        fpwr(&mut d, 0x0120, &[8, 0]);
        assert_eq!((d.state(), d.error()), (AlState::Init, Some(al_status_code::INVALID_STATE_CHANGE)));
        assert_eq!(d.memory(0x0130, 1).unwrap()[0], 0x11);
        // Up again without acknowledging: ignored.
        fpwr(&mut d, 0x0120, &[2, 0]);
        assert_eq!(d.state(), AlState::Init);
        fpwr(&mut d, 0x0120, &[0x12, 0]);
        assert_eq!((d.state(), d.error()), (AlState::PreOp, None));
        // SAFE-OP needs SM2 and SM3 as the SII says.
        fpwr(&mut d, 0x0120, &[4, 0]);
        assert_eq!((d.state(), d.error()), (AlState::PreOp, Some(al_status_code::INVALID_OUTPUT_CONFIGURATION)));
        fpwr(&mut d, 0x0810, &[0x00, 0x10, 4, 0, 0x64, 0, 1, 0]);
        fpwr(&mut d, 0x0120, &[0x14, 0]);
        assert_eq!(d.error(), Some(al_status_code::INVALID_INPUT_CONFIGURATION));
        fpwr(&mut d, 0x0818, &[0x00, 0x11, 12, 0, 0x20, 0, 1, 0]);
        fpwr(&mut d, 0x0120, &[0x14, 0]);
        assert_eq!((d.state(), d.error()), (AlState::SafeOp, None));
        fpwr(&mut d, 0x0120, &[3, 0]);
        assert_eq!(d.error(), Some(al_status_code::BOOTSTRAP_NOT_SUPPORTED));
        fpwr(&mut d, 0x0120, &[0x18, 0]);
        assert_eq!(d.state(), AlState::Op);
        fpwr(&mut d, 0x0120, &[0x05, 0]);
        assert_eq!(d.error(), Some(al_status_code::UNKNOWN_STATE));
    }

    #[test]
    fn sync_manager_areas_answer_by_direction_and_state() {
        let mut d = device(4);
        fpwr(&mut d, 0x0010, &[0x01, 0x10]);
        let read = |d: &mut TactileSubDevice, address: u16, len: usize| {
            let address = 0x1001 | u32::from(address) << 16;
            let out = run(d, FrameBuilder::new().datagram(Command::Fprd, 0, address, &vec![0xEE; len]));
            (out[0].data.clone(), out[0].working_counter)
        };
        // Plain process memory around the SyncManagers reads and writes.
        assert_eq!(fpwr(&mut d, 0x1200, &[1, 2, 3]), 1);
        assert_eq!(read(&mut d, 0x1200, 3), (vec![1, 2, 3], 1));
        fpwr(&mut d, 0x0810, &[0x00, 0x10, 4, 0, 0x64, 0, 1, 0]);
        fpwr(&mut d, 0x0818, &[0x00, 0x11, 12, 0, 0x20, 0, 1, 0]);
        // PRE-OP: the firmware keeps buffered SyncManagers deactivated.
        fpwr(&mut d, 0x0120, &[2, 0]);
        assert_eq!(read(&mut d, 0x1100, 12), (vec![0xEE; 12], 0));
        fpwr(&mut d, 0x0120, &[4, 0]);
        assert_eq!(d.state(), AlState::SafeOp);
        // SAFE-OP: inputs read (a fresh sample each time the read starts at
        // the first byte); the MainDevice may not write them, nor read SM2.
        let (inputs, wkc) = read(&mut d, 0x1100, 12);
        assert_eq!(wkc, 1);
        assert_eq!(&inputs[..4], [0, 0, 0, 0], "not acquiring yet: counter 0, status 0");
        assert_eq!(fpwr(&mut d, 0x1100, &[9; 12]), 0);
        assert_eq!(read(&mut d, 0x1000, 4), (vec![0xEE; 4], 0));
        // A read across SM2, the gap and SM3 gets the bytes it may see.
        let (bytes, wkc) = read(&mut d, 0x0FFE, 0x110);
        assert_eq!(wkc, 1);
        assert_eq!(&bytes[..6], [0, 0, 0xEE, 0xEE, 0xEE, 0xEE]);
        assert_eq!(&bytes[6..0x102], vec![0; 0xFC].as_slice());
        // Outputs apply in OP only, when the write reaches SM2's last byte.
        assert_eq!(fpwr(&mut d, 0x1000, &[1, 0, 0]), 1);
        assert_eq!(d.command_and_config(), (0, 0));
        fpwr(&mut d, 0x0120, &[8, 0]);
        fpwr(&mut d, 0x1003, &[0]);
        assert_eq!(d.command_and_config(), (1, 0));
        let (inputs, _) = read(&mut d, 0x1100, 12);
        assert_eq!(&inputs[..4], [1, 0, 1, 0], "sample 1, acquiring");
        assert_eq!(u16::from_le_bytes([inputs[6], inputs[7]]), 7 + 1);
        // A read that does not start at SM3's first byte sees the same sample.
        assert_eq!(read(&mut d, 0x1102, 2).0, [1, 0]);
        assert_eq!(d.samples(), 1);
    }

    #[test]
    fn sii_reads_eight_bytes_and_refuses_while_the_pdi_owns_it() {
        let mut d = device(4);
        let vendor = d.config().identity.vendor_id.to_le_bytes();
        fpwr(&mut d, 0x0502, &[0x00, 0x01, 0x08, 0x00, 0, 0]);
        assert_eq!(d.memory(0x0508, 4).unwrap(), vendor);
        let status = u16::from_le_bytes(d.memory(0x0502, 2).unwrap().try_into().unwrap());
        assert_eq!(status & 0x8000, 0, "never busy");
        assert_eq!(status & 0x0040, 0x0040, "8-byte reads");
        fpwr(&mut d, 0x0500, &[1]);
        fpwr(&mut d, 0x0502, &[0x00, 0x01, 0x0C, 0x00, 0, 0]);
        let status = u16::from_le_bytes(d.memory(0x0502, 2).unwrap().try_into().unwrap());
        assert_ne!(status & SII_COMMAND_ERROR, 0);
        assert_eq!(d.memory(0x0508, 4).unwrap(), vendor, "data unchanged");
    }

    #[test]
    fn a_corrupt_sii_checksum_keeps_the_segment_in_init() {
        let mut config = TactileConfig::new(4, 1);
        config.alias = 0x0042;
        let mut image = sii::tactile_image(config.identity, config.alias, 4, "x", "y");
        image[14] ^= 0xFF;
        let mut d = TactileSubDevice::with_sii(config, image, Box::new(|_: u64, _: &mut [u16]| {}));
        assert_eq!(d.memory(0x0012, 2).unwrap(), [0, 0], "alias not loaded");
        fpwr(&mut d, 0x0120, &[2, 0]);
        assert_eq!((d.state(), d.error()), (AlState::Init, Some(al_status_code::INVALID_STATE_CHANGE)));
        assert_eq!(d.memory(0x0110, 1).unwrap()[0] & 1, 0, "PDI not operational");
    }
}
