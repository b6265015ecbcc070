//! The tactile segment's process data and the firmware behind its ESC: what
//! the microcontroller on the PDI side of a real segment does.
//!
//! Process data, little-endian `u16`s:
//! * inputs, SM3 (TxPDO), at [`INPUTS_ADDRESS`]: `counter, status, taxel[N]`;
//! * outputs, SM2 (RxPDO), at [`OUTPUTS_ADDRESS`]: `command, config`.

/// Where SM2 (the outputs: command and config) starts in the ESC's memory.
pub const OUTPUTS_ADDRESS: u16 = 0x1000;
/// Bytes of outputs: `command` and `config`.
pub const OUTPUTS_BYTES: usize = 4;
/// Where SM3 (the inputs) starts in the ESC's memory.
pub const INPUTS_ADDRESS: u16 = 0x1100;
/// Bytes of inputs before the taxels: `counter` and `status`.
pub const INPUTS_HEADER_BYTES: usize = 4;
/// SM2's control byte: buffered, written by the MainDevice, PDI interrupt,
/// watchdog on.
pub const SM_CONTROL_OUTPUTS: u8 = 0x64;
/// SM3's control byte: buffered, read by the MainDevice, PDI interrupt.
pub const SM_CONTROL_INPUTS: u8 = 0x20;
/// Most taxels one segment carries: its inputs must fit the ESC's 8 KiB of
/// process memory above [`INPUTS_ADDRESS`].
pub const MAX_TAXELS: usize = 2048;

/// `command` bit: acquire (a new sample for every read of the inputs);
/// clear, the segment holds its last sample and its counter.
pub const COMMAND_ACQUIRE: u16 = 0x0001;
/// `config` bit: report taxels minus a baseline taken from the first sample
/// after the bit was set (a tare), instead of raw values.
pub const CONFIG_BASELINE: u16 = 0x0001;
/// `status` bit: the segment is acquiring.
pub const STATUS_ACQUIRING: u16 = 0x0001;
/// `status` bit: taxels are baseline-subtracted.
pub const STATUS_BASELINE: u16 = 0x0002;
/// `status` bit: the last command or config had bits this segment does not
/// know; they were ignored.
pub const STATUS_UNKNOWN_COMMAND: u16 = 0x8000;

/// Placeholder vendor ID of emulated segments. It is not an ETG-assigned ID:
/// a real skin has its maker's.
pub const EMULATED_VENDOR_ID: u32 = 0x0053_4B4E;
/// Product code of emulated tactile segments.
pub const EMULATED_PRODUCT_CODE: u32 = 0x0000_7AC7;

/// Where a segment's taxel values come from: the virtual body's contacts, a
/// test's formula. Called once per sample with the sample number (1, 2, …).
pub trait TaxelSource: Send {
    /// Fills `taxels` (raw responses) for sample number `sample`.
    fn sample(&mut self, sample: u64, taxels: &mut [u16]);
}

impl<F: FnMut(u64, &mut [u16]) + Send> TaxelSource for F {
    fn sample(&mut self, sample: u64, taxels: &mut [u16]) {
        self(sample, taxels)
    }
}

/// The segment's firmware: takes samples, obeys the command and the config.
pub(crate) struct Firmware {
    source: Box<dyn TaxelSource>,
    raw: Vec<u16>,
    baseline: Option<Vec<u16>>,
    samples: u64,
    command: u16,
    config: u16,
    unknown_command: bool,
}

impl std::fmt::Debug for Firmware {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Firmware")
            .field("taxels", &self.raw.len())
            .field("samples", &self.samples)
            .field("command", &self.command)
            .field("config", &self.config)
            .finish_non_exhaustive()
    }
}

impl Firmware {
    pub(crate) fn new(taxels: usize, source: Box<dyn TaxelSource>) -> Firmware {
        Firmware {
            source,
            raw: vec![0; taxels],
            baseline: None,
            samples: 0,
            command: 0,
            config: 0,
            unknown_command: false,
        }
    }

    /// Samples taken so far.
    pub(crate) fn samples(&self) -> u64 {
        self.samples
    }

    /// The last command and config the MainDevice sent (in OP).
    pub(crate) fn command_and_config(&self) -> (u16, u16) {
        (self.command, self.config)
    }

    /// The MainDevice starts reading the inputs buffer: as an SM3 in
    /// buffered mode hands over the newest complete buffer, the firmware
    /// writes its next sample into `inputs` (SM3's whole area) now, and the
    /// MainDevice reads that sample to its end even across frames.
    pub(crate) fn inputs_opened(&mut self, inputs: &mut [u8]) {
        let acquiring = self.command & COMMAND_ACQUIRE != 0;
        let baseline_mode = self.config & CONFIG_BASELINE != 0;
        if acquiring {
            self.samples += 1;
            self.source.sample(self.samples, &mut self.raw);
            if baseline_mode && self.baseline.is_none() {
                self.baseline = Some(self.raw.clone());
            }
        }
        let mut status = 0;
        if acquiring {
            status |= STATUS_ACQUIRING;
        }
        if baseline_mode {
            status |= STATUS_BASELINE;
        }
        if self.unknown_command {
            status |= STATUS_UNKNOWN_COMMAND;
        }
        let (header, taxels) = inputs.split_at_mut(INPUTS_HEADER_BYTES.min(inputs.len()));
        // The counter is the sample number's low 16 bits, wrapping as a
        // real segment's does.
        let counter = (self.samples & 0xFFFF) as u16;
        if header.len() == INPUTS_HEADER_BYTES {
            header[..2].copy_from_slice(&counter.to_le_bytes());
            header[2..].copy_from_slice(&status.to_le_bytes());
        }
        for (k, bytes) in taxels.chunks_exact_mut(2).enumerate() {
            let raw = self.raw.get(k).copied().unwrap_or(0);
            let value = match (&self.baseline, baseline_mode) {
                (Some(baseline), true) => raw.saturating_sub(baseline.get(k).copied().unwrap_or(0)),
                _ => raw,
            };
            bytes.copy_from_slice(&value.to_le_bytes());
        }
    }

    /// The MainDevice finished writing the outputs buffer (SM2's last byte):
    /// the firmware takes the new command and config.
    pub(crate) fn outputs_committed(&mut self, outputs: &[u8]) {
        let [c0, c1, g0, g1] = match outputs {
            [c0, c1, g0, g1, ..] => [*c0, *c1, *g0, *g1],
            _ => return,
        };
        let command = u16::from_le_bytes([c0, c1]);
        let config = u16::from_le_bytes([g0, g1]);
        self.unknown_command = command & !COMMAND_ACQUIRE != 0 || config & !CONFIG_BASELINE != 0;
        if config & CONFIG_BASELINE == 0 {
            // A later switch to baseline mode takes a new tare.
            self.baseline = None;
        }
        self.command = command & COMMAND_ACQUIRE;
        self.config = config & CONFIG_BASELINE;
    }
}
