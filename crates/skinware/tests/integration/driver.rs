//! The driver handler contains a driver's failures (error, panic, hang) to the
//! layer they happen in, and refuses to revive channels with a changed topology.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use crate::util::SegmentDir;
use skinware::{
    Driver, DriverError, DriverHandler, FrameWriter, HandlerOptions, LayerSource, LayerSpec, Reader, RtOptions,
    TopologyBuilder, WriterState,
};

#[derive(Clone, Copy, PartialEq)]
enum Behaviour {
    Good,
    Fails,
    Panics,
    Hangs,
}

struct FakeDriver {
    layers: Vec<(String, Behaviour)>,
    misbehave: Arc<AtomicBool>,
    sensors: u32,
}

struct FakeLayer {
    behaviour: Behaviour,
    misbehave: Arc<AtomicBool>,
    value: u16,
}

impl LayerSource for FakeLayer {
    fn acquire(&mut self, frame: &mut FrameWriter<'_>) -> Result<(), DriverError> {
        if self.misbehave.load(Ordering::Relaxed) {
            match self.behaviour {
                Behaviour::Good => {}
                Behaviour::Fails => return Err("bus error".into()),
                Behaviour::Panics => panic!("driver bug"),
                Behaviour::Hangs => std::thread::sleep(Duration::from_millis(400)),
            }
        }
        self.value = self.value.wrapping_add(1);
        let n = frame.len_responses();
        frame.write_responses(0, &vec![self.value; n])?;
        Ok(())
    }
}

impl Driver for FakeDriver {
    fn name(&self) -> &str {
        "fake"
    }

    fn layers(&self) -> Vec<LayerSpec> {
        self.layers
            .iter()
            .enumerate()
            .map(|(l, (name, _))| {
                let mut builder = TopologyBuilder::new(name, "pressure", 100.0);
                let first = l as u32 * 1000;
                builder.patch(1).module(1, first..first + self.sensors);
                LayerSpec { topology: builder.build().unwrap(), rt: RtOptions::default() }
            })
            .collect()
    }

    fn start(&mut self) -> Result<Vec<Box<dyn LayerSource>>, DriverError> {
        Ok(self
            .layers
            .iter()
            .map(|(_, behaviour)| {
                Box::new(FakeLayer { behaviour: *behaviour, misbehave: self.misbehave.clone(), value: 0 })
                    as Box<dyn LayerSource>
            })
            .collect())
    }
}

#[test]
fn failing_panicking_and_hanging_layers_do_not_disturb_the_good_one() {
    let dir = SegmentDir::new("handler");
    let misbehave = Arc::new(AtomicBool::new(false));
    let driver = FakeDriver {
        layers: vec![
            ("good".into(), Behaviour::Good),
            ("fails".into(), Behaviour::Fails),
            ("panics".into(), Behaviour::Panics),
            ("hangs".into(), Behaviour::Hangs),
        ],
        misbehave: misbehave.clone(),
        sensors: 64,
    };
    let options = HandlerOptions { dir: Some(dir.path.clone()), ..HandlerOptions::default() };
    let handler = DriverHandler::start("skin", Box::new(driver), &options).unwrap();
    let open = |name: &str| Reader::open_with("skin", name, &dir.reader()).unwrap();
    let (mut good, fails, panics, hangs) = (open("good"), open("fails"), open("panics"), open("hangs"));
    assert_eq!(good.topology().unwrap().sensors.len(), 64);
    good.wait_newer(Duration::from_secs(5)).unwrap();
    let before = good.writer_stats();

    misbehave.store(true, Ordering::Relaxed);
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(fails.writer_state(), WriterState::Faulted);
    assert_eq!(panics.writer_state(), WriterState::Faulted);
    assert_eq!(hangs.writer_state(), WriterState::Faulted, "the watchdog should flag a hung acquisition");
    assert_eq!(good.writer_state(), WriterState::Running);
    std::thread::sleep(Duration::from_millis(700));
    let after = good.writer_stats();
    assert_eq!(after.missed_periods, before.missed_periods, "the good layer missed periods");
    assert!(after.frames - before.frames >= 90, "the good layer slowed down: {}", after.frames - before.frames);
    assert!(fails.writer_stats().faults > 10 && panics.writer_stats().faults > 10);

    misbehave.store(false, Ordering::Relaxed);
    std::thread::sleep(Duration::from_millis(600));
    for reader in [&fails, &panics, &hangs] {
        assert_eq!(reader.writer_state(), WriterState::Running, "{} did not recover", reader.label());
    }
    handler.stop();
    assert_eq!(good.writer_state(), WriterState::Gone);
    assert!(dir.files().is_empty(), "channels left: {:?}", dir.files());
}

#[test]
fn a_restarted_driver_may_bring_another_topology() {
    let dir = SegmentDir::new("retopology");
    let keep = HandlerOptions { dir: Some(dir.path.clone()), unlink_on_stop: false, ..HandlerOptions::default() };
    let make = |sensors| FakeDriver {
        layers: vec![("arm".into(), Behaviour::Good)],
        misbehave: Arc::new(AtomicBool::new(false)),
        sensors,
    };
    DriverHandler::start("skin", Box::new(make(12)), &keep).unwrap().stop();
    // Same topology, then a changed one: each is a new channel under the name.
    DriverHandler::start("skin", Box::new(make(12)), &keep).unwrap().stop();
    let handler = DriverHandler::start("skin", Box::new(make(24)), &keep).unwrap();
    let reader = skinware::Reader::open_with("skin", "arm", &dir.reader()).unwrap();
    assert_eq!((reader.topology().unwrap().frame_bytes() / 2, reader.writer_generation()), (24, 3));
    handler.stop();
}
