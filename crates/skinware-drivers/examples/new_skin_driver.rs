//! A driver for a new CAN skin, whole: the worked example of
//! `docs/drivers.md`. The skin: M modules of 4 taxels; module `m` sends one
//! frame `0x300 + m` per sample with its 4 taxels as u16 big-endian.
//!
//! Run: `cargo run -p skinware-drivers --example new_skin_driver` (it
//! replays a log it writes, so it needs no hardware).

use std::sync::{Arc, Mutex};
use std::time::Duration;

use skinware::driver::{Driver, DriverError, LayerSource, LayerSpec};
use skinware::{DriverHandler, FrameWriter, HandlerOptions, Reader, TopologyBuilder};
use skinware_drivers::can;

/// The driver: which bus, how many modules, how fast.
struct FourTaxelSkin {
    url: String,
    modules: u16,
    rate_hz: f64,
}

impl Driver for FourTaxelSkin {
    fn name(&self) -> &str {
        "four-taxel-skin"
    }

    /// One layer, one patch; module `m` has id `m` and taxel uids `4m..4m+4`.
    fn layers(&self) -> Vec<LayerSpec> {
        let mut builder = TopologyBuilder::new("fingers", "pressure", self.rate_hz);
        builder.patch(1);
        for m in 0..u32::from(self.modules) {
            builder.module(m, 4 * m..4 * m + 4);
        }
        let topology = builder.build().expect("ids are unique by construction");
        vec![LayerSpec { topology, rt: Default::default() }]
    }

    /// Opens the bus and starts a thread that keeps the newest values.
    fn start(&mut self) -> Result<Vec<Box<dyn LayerSource>>, DriverError> {
        let mut bus = can::open(&self.url)?;
        let newest = Arc::new(Mutex::new(vec![0u16; 4 * usize::from(self.modules)]));
        let (shared, modules) = (newest.clone(), self.modules);
        std::thread::spawn(move || {
            // Ends with the bus (a log that is over, a device that is gone).
            while let Ok(received) = bus.receive(Duration::from_millis(100)) {
                let Some(frame) = received else { continue };
                let Some(m) = frame.raw_id().checked_sub(0x300).filter(|&m| m < u32::from(modules)) else {
                    continue;
                };
                if frame.bytes().len() != 8 {
                    continue;
                }
                let mut values = skinware::lock(&shared);
                for (k, pair) in frame.bytes().chunks_exact(2).enumerate() {
                    values[4 * m as usize + k] = u16::from_be_bytes([pair[0], pair[1]]);
                }
            }
        });
        Ok(vec![Box::new(Fingers { newest })])
    }
}

/// The layer: each acquisition copies the newest values.
struct Fingers {
    newest: Arc<Mutex<Vec<u16>>>,
}

impl LayerSource for Fingers {
    fn acquire(&mut self, frame: &mut FrameWriter<'_>) -> Result<(), DriverError> {
        let values = skinware::lock(&self.newest);
        frame.write_responses(0, &values)?;
        Ok(())
    }
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // A recorded sample of 3 modules, as `candump -l` writes it.
    let dir = std::env::temp_dir().join(format!("four-taxel-skin-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let log = dir.join("fingers.log");
    std::fs::write(
        &log,
        "(0.000000) can0 300#0001000200030004\n(0.001000) can0 301#0005000600070008\n(0.002000) can0 302#0009000A000B000C\n",
    )?;
    let driver = FourTaxelSkin { url: format!("candump://{}?loop=true", log.display()), modules: 3, rate_hz: 50.0 };
    let options = HandlerOptions { dir: Some(dir.clone()), ..HandlerOptions::default() };
    let handler = DriverHandler::start("example", Box::new(driver), &options)?;
    let mut reader = Reader::open_with(
        "example",
        "fingers",
        &skinware::ReaderOptions { dir: Some(dir.clone()), ..Default::default() },
    )?;
    std::thread::sleep(Duration::from_millis(100));
    let frame = reader.wait_newer(Duration::from_secs(1))?;
    println!("fingers: {:?}", frame.responses());
    assert_eq!(frame.responses(), (1..=12).collect::<Vec<u16>>());
    handler.stop();
    std::fs::remove_dir_all(&dir)?;
    Ok(())
}
