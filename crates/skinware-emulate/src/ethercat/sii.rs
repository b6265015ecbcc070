//! The SubDevice Information Interface (SII) EEPROM image of a tactile
//! segment (ETG2010): identity, General, FMMU, SyncManager, TxPDO and RxPDO
//! categories, as a MainDevice reads them through registers 0x0500–0x050F.

use super::tactile::{
    INPUTS_ADDRESS, INPUTS_HEADER_BYTES, OUTPUTS_ADDRESS, OUTPUTS_BYTES, SM_CONTROL_INPUTS, SM_CONTROL_OUTPUTS,
};

/// Word address of the first category (ETG2010 Table 2).
pub const FIRST_CATEGORY_WORD: usize = 0x40;
/// Category types (ETG2010 Table 3).
const CATEGORY_STRINGS: u16 = 10;
const CATEGORY_GENERAL: u16 = 30;
const CATEGORY_FMMU: u16 = 40;
const CATEGORY_SYNC_MANAGER: u16 = 41;
const CATEGORY_TXPDO: u16 = 50;
const CATEGORY_RXPDO: u16 = 51;
const CATEGORY_END: u16 = 0xFFFF;
/// SyncManager types in the SyncManager category.
const SM_TYPE_MAILBOX_OUT: u8 = 1;
const SM_TYPE_MAILBOX_IN: u8 = 2;
const SM_TYPE_OUTPUTS: u8 = 3;
const SM_TYPE_INPUTS: u8 = 4;
/// FMMU usages in the FMMU category.
const FMMU_OUTPUTS: u8 = 1;
const FMMU_INPUTS: u8 = 2;
const FMMU_SM_STATUS: u8 = 3;
/// CoE data type UNSIGNED16 (ETG1000.6 Table 64).
const DATA_TYPE_UNSIGNED16: u8 = 0x06;
/// A PDO holds at most 255 entries (a `u8` count); taxels are split into
/// PDOs of this many, which keeps the PDO count far below ethercrab's 64.
pub const TAXELS_PER_PDO: usize = 240;
/// Object index of the TxPDO with the counter and the status.
pub const TXPDO_HEADER_INDEX: u16 = 0x1A00;
/// Object index of the first TxPDO of taxels; the next ones follow.
pub const TXPDO_TAXELS_INDEX: u16 = 0x1A01;
/// Object index of the RxPDO with the command and the configuration.
pub const RXPDO_INDEX: u16 = 0x1600;

/// Identity of a SubDevice, as its SII holds it at word 0x0008.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Identity {
    /// ETG vendor ID.
    pub vendor_id: u32,
    /// Product code.
    pub product_code: u32,
    /// Revision number.
    pub revision: u32,
    /// Serial number.
    pub serial: u32,
}

/// The CRC-8 of the SII's first 14 bytes (polynomial 0x07, initial 0xFF),
/// stored in word 7; an ESC refuses its configuration if it is wrong.
pub fn checksum(bytes: &[u8]) -> u8 {
    let mut crc = 0xFFu8;
    for &byte in bytes {
        crc ^= byte;
        for _ in 0..8 {
            crc = if crc & 0x80 != 0 { (crc << 1) ^ 0x07 } else { crc << 1 };
        }
    }
    crc
}

/// The SII image of a tactile segment with `taxels` taxels: inputs at
/// [`INPUTS_ADDRESS`] through SM3, outputs at [`OUTPUTS_ADDRESS`] through SM2,
/// no mailbox (the PDO map is fixed, read from the SII).
pub fn tactile_image(identity: Identity, alias: u16, taxels: usize, order: &str, name: &str) -> Vec<u8> {
    let mut image = vec![0u8; FIRST_CATEGORY_WORD * 2];
    let put_u16 = |image: &mut Vec<u8>, word: usize, value: u16| {
        image[word * 2..word * 2 + 2].copy_from_slice(&value.to_le_bytes());
    };
    // PDI control: SPI, as on a LAN9252-class ESC behind a microcontroller.
    put_u16(&mut image, 0x0000, 0x0005);
    put_u16(&mut image, 0x0004, alias);
    let crc = checksum(&image[..14]);
    put_u16(&mut image, 0x0007, u16::from(crc));
    for (word, value) in [(0x0008, identity.vendor_id), (0x000A, identity.product_code)]
        .into_iter()
        .chain([(0x000C, identity.revision), (0x000E, identity.serial)])
    {
        image[word * 2..word * 2 + 4].copy_from_slice(&value.to_le_bytes());
    }
    // Version 1 of the SII layout; the size word is filled in below.
    put_u16(&mut image, 0x003F, 1);

    // Strings: 1 is the order code (ethercrab's SubDevice name), 2 the name.
    let mut strings = vec![2u8];
    for text in [order, name] {
        let bytes = &text.as_bytes()[..text.len().min(255)];
        strings.push(bytes.len() as u8);
        strings.extend_from_slice(bytes);
    }
    push_category(&mut image, CATEGORY_STRINGS, &strings);

    // General: group, image, order and name string indices; no CoE, FoE or
    // EoE; 32 bytes as ETG2010 Table 5 lays them out.
    let mut general = [0u8; 32];
    general[2] = 1;
    general[3] = 2;
    push_category(&mut image, CATEGORY_GENERAL, &general);

    push_category(&mut image, CATEGORY_FMMU, &[FMMU_OUTPUTS, FMMU_INPUTS, FMMU_SM_STATUS, 0xFF]);

    let inputs_len = (INPUTS_HEADER_BYTES + 2 * taxels) as u16;
    let mut sync_managers = Vec::new();
    for (start, len, control, enable, sm_type) in [
        // The mailbox SyncManagers exist in the ESC but the segment has no
        // mailbox: disabled, zero length.
        (0x1800u16, 0u16, 0x26u8, 0u8, SM_TYPE_MAILBOX_OUT),
        (0x1880, 0, 0x22, 0, SM_TYPE_MAILBOX_IN),
        (OUTPUTS_ADDRESS, OUTPUTS_BYTES as u16, SM_CONTROL_OUTPUTS, 1, SM_TYPE_OUTPUTS),
        (INPUTS_ADDRESS, inputs_len, SM_CONTROL_INPUTS, 1, SM_TYPE_INPUTS),
    ] {
        sync_managers.extend_from_slice(&start.to_le_bytes());
        sync_managers.extend_from_slice(&len.to_le_bytes());
        sync_managers.extend_from_slice(&[control, 0, enable, sm_type]);
    }
    push_category(&mut image, CATEGORY_SYNC_MANAGER, &sync_managers);

    let mut txpdo = Vec::new();
    push_pdo(&mut txpdo, TXPDO_HEADER_INDEX, 3, &[(0x6000, 1), (0x6000, 2)]);
    for (chunk, first) in (0..taxels).step_by(TAXELS_PER_PDO).enumerate() {
        let count = TAXELS_PER_PDO.min(taxels - first);
        let object = 0x6001 + chunk as u16;
        let entries: Vec<(u16, u8)> = (1..=count as u8).map(|sub| (object, sub)).collect();
        push_pdo(&mut txpdo, TXPDO_TAXELS_INDEX + chunk as u16, 3, &entries);
    }
    push_category(&mut image, CATEGORY_TXPDO, &txpdo);

    let mut rxpdo = Vec::new();
    push_pdo(&mut rxpdo, RXPDO_INDEX, 2, &[(0x7000, 1), (0x7000, 2)]);
    push_category(&mut image, CATEGORY_RXPDO, &rxpdo);

    image.extend_from_slice(&CATEGORY_END.to_le_bytes());
    image.extend_from_slice(&0u16.to_le_bytes());

    // The EEPROM's size in kilobits, a power of two as real parts come; the
    // rest reads as erased (0xFF).
    let kilobits = (image.len() * 8).div_ceil(1024).next_power_of_two().max(2);
    image.resize(kilobits * 1024 / 8, 0xFF);
    image[0x3E * 2..0x3E * 2 + 2].copy_from_slice(&(kilobits as u16 - 1).to_le_bytes());
    image
}

/// Appends a category: type, length in words, data padded to a whole word.
fn push_category(image: &mut Vec<u8>, category: u16, data: &[u8]) {
    let words = data.len().div_ceil(2);
    image.extend_from_slice(&category.to_le_bytes());
    image.extend_from_slice(&(words as u16).to_le_bytes());
    image.extend_from_slice(data);
    if !data.len().is_multiple_of(2) {
        image.push(0);
    }
}

/// Appends a PDO (ETG2010 Table 14) of 16-bit entries on SyncManager `sm`.
fn push_pdo(category: &mut Vec<u8>, index: u16, sm: u8, entries: &[(u16, u8)]) {
    category.extend_from_slice(&index.to_le_bytes());
    category.push(entries.len() as u8);
    category.push(sm);
    // No DC sync, no name string; flags: mandatory, fixed content.
    category.extend_from_slice(&[0, 0]);
    category.extend_from_slice(&0x0011u16.to_le_bytes());
    for &(object, sub_index) in entries {
        category.extend_from_slice(&object.to_le_bytes());
        category.push(sub_index);
        category.push(0);
        category.push(DATA_TYPE_UNSIGNED16);
        category.push(16);
        category.extend_from_slice(&0u16.to_le_bytes());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Walks the categories of an image the way a MainDevice does.
    fn categories(image: &[u8]) -> Vec<(u16, Vec<u8>)> {
        let mut word = FIRST_CATEGORY_WORD;
        let mut out = Vec::new();
        loop {
            let category = u16::from_le_bytes([image[word * 2], image[word * 2 + 1]]);
            let len = usize::from(u16::from_le_bytes([image[word * 2 + 2], image[word * 2 + 3]]));
            if category == CATEGORY_END {
                return out;
            }
            out.push((category, image[word * 2 + 4..word * 2 + 4 + len * 2].to_vec()));
            word += 2 + len;
        }
    }

    #[test]
    fn checksum_agrees_with_an_independent_crc_implementation() {
        // The `crc` crate with the parameters ethercrab uses for the same
        // checksum: width 8, polynomial 0x07, initial 0xFF, no reflection.
        const SII: crc::Algorithm<u8> = crc::Algorithm {
            width: 8,
            poly: 0x07,
            init: 0xFF,
            refin: false,
            refout: false,
            xorout: 0x00,
            check: 0xFB,
            residue: 0x00,
        };
        let reference = crc::Crc::<u8>::new(&SII);
        for bytes in [&b"123456789"[..], &[0u8; 14], &[0x05, 0, 0, 0, 0, 0, 0, 0, 0xAD, 0x0B, 0, 0, 0, 0]] {
            assert_eq!(checksum(bytes), reference.checksum(bytes));
        }
    }

    #[test]
    fn image_holds_identity_pdos_and_sizes() {
        let identity = Identity { vendor_id: 0x1234_5678, product_code: 0x0102_0304, revision: 7, serial: 42 };
        let image = tactile_image(identity, 0x0BAD, 708, "SKIN-T708", "tactile");
        assert_eq!(u16::from_le_bytes([image[8], image[9]]), 0x0BAD);
        assert_eq!(u16::from(checksum(&image[..14])), u16::from_le_bytes([image[14], image[15]]));
        assert_eq!(u32::from_le_bytes(image[16..20].try_into().unwrap()), 0x1234_5678);
        assert_eq!(u32::from_le_bytes(image[28..32].try_into().unwrap()), 42);
        let kilobits = usize::from(u16::from_le_bytes([image[0x7C], image[0x7D]])) + 1;
        assert_eq!(image.len(), kilobits * 128);
        let found = categories(&image);
        let types: Vec<u16> = found.iter().map(|(t, _)| *t).collect();
        assert_eq!(types, [10, 30, 40, 41, 50, 51]);
        // The TxPDOs add up to the counter, the status and 708 taxels, in 16 bits each.
        let txpdo = &found[4].1;
        let mut offset = 0;
        let mut bits = 0usize;
        let mut pdos = 0;
        while offset < txpdo.len() {
            let entries = usize::from(txpdo[offset + 2]);
            assert_eq!(txpdo[offset + 3], 3, "TxPDOs are on SM3");
            for entry in 0..entries {
                bits += usize::from(txpdo[offset + 8 + entry * 8 + 5]);
            }
            offset += 8 + entries * 8;
            pdos += 1;
        }
        assert_eq!(bits, (2 + 708) * 16);
        assert_eq!(pdos, 1 + 708usize.div_ceil(TAXELS_PER_PDO));
        // SM3's length is the same number of bytes.
        let sm3 = &found[3].1[24..32];
        assert_eq!(u16::from_le_bytes([sm3[2], sm3[3]]), (4 + 2 * 708) as u16);
    }
}
