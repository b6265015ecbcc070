//! The segment firmware's side of the ESC: the AL state machine (the
//! transitions the MainDevice asks for, checked against the SyncManager
//! configuration the SII describes) and the SII EEPROM interface.

use super::*;

impl TactileSubDevice {
    /// The AL state machine: the MainDevice asks for a state.
    pub(super) fn al_control(&mut self, control: u8) {
        let requested = control & 0x0F;
        let acknowledge = control & 0x10 != 0;
        let current = self.state;
        let upward = requested > current.code();
        if acknowledge {
            self.error = None;
        } else if self.error.is_some() && upward {
            // With the error flag set, only an acknowledgement lets the
            // segment go up again.
            return;
        }
        let next = match (current, requested) {
            (_, 1) => Ok(AlState::Init),
            (_, 2) if current != AlState::Init || self.sii_checksum_ok => Ok(AlState::PreOp),
            (_, 2) => Err(al_status_code::INVALID_STATE_CHANGE),
            (_, 3) => Err(al_status_code::BOOTSTRAP_NOT_SUPPORTED),
            (AlState::PreOp, 4) => self.check_process_data_configuration().map(|()| AlState::SafeOp),
            (AlState::SafeOp | AlState::Op, 4) => Ok(AlState::SafeOp),
            (AlState::SafeOp | AlState::Op, 8) => Ok(AlState::Op),
            (AlState::Init, 4) | (AlState::Init | AlState::PreOp, 8) => Err(al_status_code::INVALID_STATE_CHANGE),
            _ => Err(al_status_code::UNKNOWN_STATE),
        };
        match next {
            Ok(state) => {
                if state == AlState::Op && current != AlState::Op {
                    self.op_since = Some(Instant::now());
                    self.op_cycles = 0;
                } else if state != AlState::Op {
                    self.op_since = None;
                }
                self.state = state;
            }
            Err(code) => self.error = Some(code),
        }
        self.store_al_status();
    }

    /// PRE-OP to SAFE-OP: the firmware checks that SM2 and SM3 are set up as
    /// its SII says (start, length, direction, buffered, enabled).
    pub(super) fn check_process_data_configuration(&self) -> Result<(), u16> {
        let sync_manager = |n: usize| {
            let base = usize::from(SYNC_MANAGER_BASE) + n * 8;
            let r = &self.memory[base..base + 8];
            (u16::from_le_bytes([r[0], r[1]]), usize::from(u16::from_le_bytes([r[2], r[3]])), r[4] & 0x0F, r[6] & 0x01)
        };
        // Buffered mode (0b00) with the MainDevice writing (0b01 << 2).
        if sync_manager(2) != (OUTPUTS_ADDRESS, OUTPUTS_BYTES, 0x04, 1) {
            return Err(al_status_code::INVALID_OUTPUT_CONFIGURATION);
        }
        if sync_manager(3) != (INPUTS_ADDRESS, INPUTS_HEADER_BYTES + 2 * self.config.taxels, 0x00, 1) {
            return Err(al_status_code::INVALID_INPUT_CONFIGURATION);
        }
        Ok(())
    }

    /// Runs the SII command just written to the control register.
    pub(super) fn sii_command(&mut self) {
        let control = u16::from_le_bytes([self.memory[REG_SII_CONTROL], self.memory[REG_SII_CONTROL + 1]]);
        let mut status = SII_READ_8_BYTES | SII_ADDRESS_16_BIT | (control & SII_WRITE_ENABLE);
        if !self.sii_checksum_ok {
            status |= SII_CHECKSUM_ERROR;
        }
        // Bit 0 of the configuration register hands the SII to the PDI;
        // bit 1 forces it back to EtherCAT.
        let pdi_owns = self.memory[REG_SII_CONFIG] & 0x03 == 0x01;
        let word = usize::from(u16::from_le_bytes([self.memory[REG_SII_ADDRESS], self.memory[REG_SII_ADDRESS + 1]]));
        match control & SII_COMMAND_MASK {
            0 => {}
            _ if pdi_owns => status |= SII_COMMAND_ERROR,
            SII_COMMAND_READ => {
                for k in 0..SII_READ_BYTES {
                    // Beyond the image an EEPROM reads erased.
                    self.memory[REG_SII_DATA + k] = self.sii.get(word * 2 + k).copied().unwrap_or(0xFF);
                }
            }
            SII_COMMAND_WRITE if control & SII_WRITE_ENABLE == 0 => status |= SII_COMMAND_ERROR,
            SII_COMMAND_WRITE => match self.sii.get_mut(word * 2..word * 2 + 2) {
                Some(target) => target.copy_from_slice(&self.memory[REG_SII_DATA..REG_SII_DATA + 2]),
                None => status |= SII_WRITE_ERROR,
            },
            SII_COMMAND_RELOAD => {
                self.sii_checksum_ok = self.sii.len() >= 16
                    && u16::from(sii::checksum(&self.sii[..14])) == u16::from_le_bytes([self.sii[14], self.sii[15]]);
                self.reload_sii();
                self.store_dl_status();
                if !self.sii_checksum_ok {
                    status |= SII_CHECKSUM_ERROR;
                }
            }
            _ => status |= SII_COMMAND_ERROR,
        }
        self.store_sii_status(status);
    }
}
