//! A published geometry file from arbitrary bytes. The input is taken as the
//! file without its checksum, and the checksum is made right, so that the
//! fuzzer explores the decoder past it (a wrong checksum is rejected first).
#![no_main]

use libfuzzer_sys::fuzz_target;
use skinware_geometry::SkinGeometry;

/// FNV-1a 64 over the bytes and then one 0xff byte: the file's checksum.
fn checksum(bytes: &[u8]) -> u64 {
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes.iter().chain(&[0xff]) {
        hash = (hash ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
    }
    hash
}

fuzz_target!(|body: &[u8]| {
    let mut file = body.to_vec();
    file.extend_from_slice(&checksum(body).to_le_bytes());
    if let Ok(geometry) = SkinGeometry::decode(&file) {
        // Every index a user may follow is in range.
        for sensor in 0..geometry.sensor_count() {
            let _ = geometry.neighbours_of(sensor);
            let _ = geometry.locate(sensor);
        }
    }
    let _ = SkinGeometry::decode(body);
});
