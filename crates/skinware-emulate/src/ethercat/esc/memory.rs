//! What the MainDevice's reads and writes reach: the registers (which exist,
//! which it may write), and process memory through the FMMUs and the
//! SyncManagers (buffered, by direction and AL state). A write to AL control
//! or to SII control hands over to the firmware ([`super::al`]).

use super::*;

impl TactileSubDevice {
    /// Reads `out.len()` bytes from `start`; returns whether any byte was
    /// accessible. Starting at an input SyncManager's first byte takes a new
    /// sample.
    pub(super) fn read(&mut self, start: u32, out: &mut [u8], or: bool) -> bool {
        if let Some((n, sm_start, sm_length, false)) = self.sync_manager_at(start)
            && sm_start == start
            && self.sync_manager_accessible(n, false, Access::Read)
        {
            let range = sm_start as usize..(sm_start + sm_length) as usize;
            if range.end <= self.memory.len() && self.is_inputs(sm_start, sm_length) {
                self.firmware.inputs_opened(&mut self.memory[range]);
            }
        }
        let end = start + out.len() as u32;
        let mut address = start;
        let mut any = false;
        while address < end {
            let index = (address - start) as usize;
            if address < PROCESS_MEMORY_START {
                if Self::present(address) {
                    let value = self.memory[address as usize];
                    out[index] = if or { out[index] | value } else { value };
                    any = true;
                }
                address += 1;
                continue;
            }
            let (run_end, accessible, _) = self.process_run(address, end, Access::Read);
            if accessible {
                let source = &self.memory[address as usize..run_end as usize];
                let target = &mut out[index..(run_end - start) as usize];
                if or {
                    target.iter_mut().zip(source).for_each(|(t, s)| *t |= s);
                } else {
                    target.copy_from_slice(source);
                }
                any = true;
            }
            address = run_end;
        }
        any
    }

    /// Whether a SyncManager area is the segment's inputs (SM3's area as the
    /// SII describes it): only there does the firmware put samples.
    pub(super) fn is_inputs(&self, start: u32, length: u32) -> bool {
        start == u32::from(INPUTS_ADDRESS) && length as usize == INPUTS_HEADER_BYTES + 2 * self.config.taxels
    }

    /// Writes `data` at `start`; returns whether any byte was accessible.
    /// Then runs what the writes trigger: AL control, SII commands, outputs.
    pub(super) fn write(&mut self, start: u32, data: &[u8]) -> bool {
        let mut any = false;
        let mut touched_al_control = false;
        let mut touched_sii_control = false;
        let mut completed_outputs = None;
        let end = start + data.len() as u32;
        let mut address = start;
        while address < end {
            let index = (address - start) as usize;
            if address < PROCESS_MEMORY_START {
                if Self::present(address) {
                    if Self::register_writable(address) {
                        self.memory[address as usize] = data[index];
                        touched_al_control |= address == REG_AL_CONTROL as u32;
                        touched_sii_control |= (REG_SII_CONTROL as u32..REG_SII_CONTROL as u32 + 2).contains(&address);
                    }
                    any = true;
                }
                address += 1;
                continue;
            }
            let (run_end, accessible, sync_manager) = self.process_run(address, end, Access::Write);
            if accessible {
                self.memory[address as usize..run_end as usize]
                    .copy_from_slice(&data[index..(run_end - start) as usize]);
                if let Some((sm_start, sm_length, true)) = sync_manager
                    && run_end == sm_start + sm_length
                {
                    completed_outputs = Some((sm_start, sm_length));
                }
                any = true;
            }
            address = run_end;
        }
        if touched_al_control {
            self.al_control(self.memory[REG_AL_CONTROL]);
        }
        if touched_sii_control {
            self.sii_command();
        }
        if let Some((sm_start, sm_length)) = completed_outputs
            && sm_start == u32::from(OUTPUTS_ADDRESS)
            && sm_length as usize == OUTPUTS_BYTES
            && self.state == AlState::Op
        {
            // Outputs apply in OP only; in SAFE-OP they stay in their safe state.
            let range = sm_start as usize..(sm_start + sm_length) as usize;
            let outputs: [u8; OUTPUTS_BYTES] = self.memory[range].try_into().unwrap_or([0; OUTPUTS_BYTES]);
            self.firmware.outputs_committed(&outputs);
        }
        any
    }

    /// Whether ESC memory at `address` exists for the EtherCAT side.
    pub(super) fn present(address: u32) -> bool {
        match address {
            // FMMUs 8–15 and SyncManagers 8–15 are not implemented; no DC.
            0x0680..=0x06FF | 0x0840..=0x087F | 0x0900..=0x09FF => false,
            a if a < PROCESS_MEMORY_START => true,
            a => a < PROCESS_MEMORY_START + PROCESS_MEMORY_BYTES as u32,
        }
    }

    /// Whether the EtherCAT side may write a register (the rest are read-only
    /// to it: writes are ignored but still counted, as an ESC does).
    pub(super) fn register_writable(address: u32) -> bool {
        let sm_end = u32::from(SYNC_MANAGER_BASE) + (SYNC_MANAGERS * 8) as u32;
        match address {
            0x0010..=0x0011 | 0x0100..=0x0103 | 0x0120..=0x0121 => true,
            0x0400..=0x0401 | 0x0410..=0x0411 | 0x0420..=0x0421 | 0x0440..=0x0443 => true,
            0x0500 | 0x0502..=0x050F => true,
            0x0600..=0x067F => true,
            a if (u32::from(SYNC_MANAGER_BASE)..sm_end).contains(&a) => {
                // Status (byte 5) and PDI control (byte 7) are read-only.
                !matches!((a - u32::from(SYNC_MANAGER_BASE)) % 8, 5 | 7)
            }
            _ => false,
        }
    }

    /// The buffered SyncManager covering process memory at `address`, if
    /// any: `(index, start, length, master writes)`.
    pub(super) fn sync_manager_at(&self, address: u32) -> Option<(usize, u32, u32, bool)> {
        (0..SYNC_MANAGERS).find_map(|n| {
            let base = usize::from(SYNC_MANAGER_BASE) + n * 8;
            let register = &self.memory[base..base + 8];
            let start = u32::from(u16::from_le_bytes([register[0], register[1]]));
            let length = u32::from(u16::from_le_bytes([register[2], register[3]]));
            let enabled = register[6] & 0x01 != 0;
            (enabled && length > 0 && (start..start + length).contains(&address)).then(|| {
                let master_writes = (register[4] >> 2) & 0x03 == 0x01;
                (n, start, length, master_writes)
            })
        })
    }

    /// Whether the EtherCAT side can access the area of SyncManager `n`
    /// (which `master_writes` or not) this way, given its mode and the state.
    pub(super) fn sync_manager_accessible(&self, n: usize, master_writes: bool, access: Access) -> bool {
        let base = usize::from(SYNC_MANAGER_BASE) + n * 8;
        let buffered = self.memory[base + 4] & 0x03 == 0x00;
        let active = matches!(self.state, AlState::SafeOp | AlState::Op);
        buffered && active && master_writes == (access == Access::Write)
    }

    /// The run of process memory from `address` (up to `end`) that one rule
    /// covers, so that accesses copy whole runs instead of deciding byte by
    /// byte: `(run end, accessible, the covering SyncManager's area and
    /// whether the master writes it)`. A run stops where a SyncManager's area
    /// ends or another's starts, which gives every byte the rule a byte-wise
    /// lookup (the lowest-numbered SyncManager covering it) would.
    pub(super) fn process_run(&self, address: u32, end: u32, access: Access) -> (u32, bool, Option<(u32, u32, bool)>) {
        let memory_end = PROCESS_MEMORY_START + PROCESS_MEMORY_BYTES as u32;
        if address >= memory_end {
            return (end, false, None);
        }
        let mut run_end = end.min(memory_end);
        for n in 0..SYNC_MANAGERS {
            let base = usize::from(SYNC_MANAGER_BASE) + n * 8;
            let register = &self.memory[base..base + 8];
            let sm_start = u32::from(u16::from_le_bytes([register[0], register[1]]));
            if register[6] & 0x01 != 0 && register[2..4] != [0, 0] && sm_start > address {
                run_end = run_end.min(sm_start);
            }
        }
        match self.sync_manager_at(address) {
            Some((n, sm_start, sm_length, master_writes)) => {
                run_end = run_end.min(sm_start + sm_length);
                let accessible = self.sync_manager_accessible(n, master_writes, access);
                (run_end, accessible, Some((sm_start, sm_length, master_writes)))
            }
            None => (run_end, true, None),
        }
    }
}
