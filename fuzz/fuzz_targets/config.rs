//! A `skin run` configuration from arbitrary text, through every check that
//! loading it makes (the drivers are built, the services and regions checked):
//! a config or an error, never a panic, a hang or an allocation the text does
//! not justify.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use skin::config::Config;

fuzz_target!(|bytes: &[u8]| {
    if let Ok(text) = std::str::from_utf8(bytes) {
        if let Ok(config) = Config::parse(text, Path::new("fuzz/skin.toml")) {
            // What the commands derive from an accepted config must hold too.
            for region in &config.regions {
                region.spec().expect("a loaded config's regions have specs");
            }
            for service in &config.services {
                let _ = (service.mode(), service.contact(), service.motion());
            }
        }
    }
});
