//! An application-based service: an application that reads the layers of a
//! skin and also publishes what it computes, here the hottest taxel of each
//! body part, for other applications.
//!
//! To be self-contained it starts its own small virtual skin in this process;
//! against a real skin, drop that part and give the running skin's name.
//!
//!     cargo run --release -p skinware-services --example application_service

use std::time::{Duration, Instant};

use skinware::{Driver, DriverHandler, FrameStatus, HandlerOptions, Ticker, WriterOptions};
use skinware_drivers::{VirtualSkin, VirtualSkinConfig};
use skinware_geometry::{RegionSpec, Selector, SkinGeometry};
use skinware_services::SkinInputs;
use skinware_services::framework::{ServiceMode, ServicePayload, ServiceReader, ServiceSpec, ServiceWriter};

/// The record this application publishes per region.
#[derive(Clone, Copy, Debug, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
struct Hottest {
    sensor: u32,
    response: u32,
}

impl ServicePayload for Hottest {
    const SCHEMA: &'static str = "example.hottest";
    const VERSION: u32 = 1;
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let skin = format!("appservice{}", std::process::id());
    let driver = VirtualSkin::new(VirtualSkinConfig { sensors: 3000, layers: 2, ..VirtualSkinConfig::default() })?;
    let layers: Vec<_> = driver.layers().into_iter().map(|l| l.topology).collect();
    let parts = ["torso", "left_forearm", "right_forearm"];
    let regions: Vec<RegionSpec> =
        parts.iter().map(|p| RegionSpec { name: (*p).into(), selectors: vec![Selector::Link((*p).into())] }).collect();
    let geometry = SkinGeometry::build(&skin, &layers, &driver.calibration(), &regions)?;
    let handler = DriverHandler::start(&skin, Box::new(driver), &HandlerOptions::default())?;

    // The application: reads every layer, and publishes one record per region.
    let mut inputs = SkinInputs::new(&skin, &geometry);
    let spec = ServiceSpec::new(
        "hottest",
        parts.iter().map(|p| (*p).to_owned()).collect(),
        ServiceMode::Periodic { hz: 20.0 },
    );
    let mut service = ServiceWriter::<Hottest>::create(&skin, &spec, &WriterOptions::default())?;
    // Any other application reads it by name, typed.
    let mut user: Option<ServiceReader<Hottest>> = None;

    let mut ticker = Ticker::from_hz(20.0);
    let started = Instant::now();
    let mut printed = 0;
    while started.elapsed() < Duration::from_secs(3) {
        ticker.wait(handler.stop_signal());
        let all_up = inputs.update();
        let records: Vec<Hottest> = geometry
            .regions
            .sensors
            .iter()
            .map(|sensors| {
                // A sensor whose layer is down has no response: it is never the hottest.
                let response = |s: u32| inputs.response(s as usize).unwrap_or(0);
                let hottest = sensors.iter().copied().max_by_key(|&s| response(s)).unwrap_or(0);
                Hottest { sensor: hottest, response: u32::from(response(hottest)) }
            })
            .collect();
        let status = if all_up { FrameStatus::OK } else { FrameStatus::INPUT_FAULTED };
        service.publish(&records, status)?;

        let reader = match &mut user {
            Some(reader) => reader,
            None => user.insert(ServiceReader::<Hottest>::open(&skin, "hottest")?),
        };
        let labels = reader.labels().to_vec();
        let frame = reader.latest()?;
        if frame.seq % 20 == 0 {
            for (label, record) in labels.iter().zip(frame.records) {
                let place = geometry.locate(record.sensor as usize).expect("a sensor of the skin");
                println!(
                    "frame {}: {label:>14}: hottest taxel uid {} (module {}), response {}",
                    frame.seq, place.uid, place.module_id, record.response
                );
            }
            printed += 1;
        }
    }
    handler.stop();
    assert!(printed >= 2, "the application service published too little");
    Ok(())
}
