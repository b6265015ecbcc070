//! What a `ros2` driver takes from the network: a message of its topic's
//! type, any bytes (a forged writer can send anything under the type's
//! name). The first byte picks the type and the sensors (1..=64); the rest
//! is the message. Any bytes give a frame or an error, never a panic.
#![no_main]

use libfuzzer_sys::fuzz_target;
use skinware_ros2::input::{Ros2Input, decode};

fuzz_target!(|bytes: &[u8]| {
    let Some((&pick, message)) = bytes.split_first() else { return };
    let input = match pick % 3 {
        0 => Ros2Input::PointCloud2 { field: "response".into() },
        1 => Ros2Input::UInt16MultiArray,
        _ => Ros2Input::Float32MultiArray,
    };
    let mut out = vec![0u16; usize::from(pick / 3 % 64) + 1];
    let _ = decode(message, &input, &mut out);
});
