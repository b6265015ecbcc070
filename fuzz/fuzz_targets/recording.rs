//! A recording (an MCAP file) from arbitrary bytes: the record stream, the
//! header, every frame's CDR and the scan behind `skin info`, as `skin info`,
//! `skin replay` and `--recover` read a file someone hands them.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use skinware_record::file::{RecordStream, scan_stream};

fuzz_target!(|bytes: &[u8]| {
    // Files start with the MCAP magic; the fuzzer need not find it.
    let mut file = skinware_record::mcap::MAGIC.to_vec();
    file.extend_from_slice(bytes);
    if let Ok(stream) = RecordStream::from_reader(Path::new("fuzz.mcap"), std::io::Cursor::new(file.clone())) {
        let _ = scan_stream(stream, file.len() as u64);
    }
    let _ = skinware_ros2::decode::<skinware_ros2::SkinFrame>(bytes, "SkinFrame");
    let _ = skinware_ros2::decode::<skinware_ros2::Image>(bytes, "Image");
});
