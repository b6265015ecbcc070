//! A text message from the viewer's page (a browser, or anything that opens
//! the WebSocket) from arbitrary bytes: a message or a typed error, never a
//! panic, and never a periodic rate outside the range the server reads at.
#![no_main]

use libfuzzer_sys::fuzz_target;
use skinware_viewer::message::{self, ClientMessage, MAX_PERIODIC_HZ, MIN_PERIODIC_HZ, ReadMode};

fuzz_target!(|bytes: &[u8]| {
    // tungstenite hands over text messages only once they are valid UTF-8.
    if let Ok(text) = std::str::from_utf8(bytes) {
        match message::decode(text) {
            Ok(ClientMessage::Mode(ReadMode::Periodic { rate_hz })) => {
                assert!((MIN_PERIODIC_HZ..=MAX_PERIODIC_HZ).contains(&rate_hz), "{rate_hz} Hz accepted");
            }
            Ok(_) => {}
            Err(e) => {
                let _ = e.to_string();
            }
        }
    }
});
