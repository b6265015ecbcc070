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

    // No timing here (a loaded machine may run the good layer late too):
    // each state is waited for, and the good layer must publish, unfaulted,
    // while the hanging layer is stuck inside its acquisition.
    misbehave.store(true, Ordering::Relaxed);
    for (reader, what) in [(&fails, "a failing acquisition"), (&panics, "a panic"), (&hangs, "a hung acquisition")] {
        wait_for_state(reader, WriterState::Faulted, what);
    }
    let mut fresh_while_others_faulted = 0;
    while fresh_while_others_faulted < 30 {
        let frame = good.wait_newer(Duration::from_secs(10)).expect("the good layer stopped publishing");
        assert!(!frame.status().is_fault(), "the good layer's frame is faulted");
        fresh_while_others_faulted += 1;
    }
    assert_eq!(good.writer_state(), WriterState::Running);
    assert_eq!(good.writer_stats().faults, before.faults, "the good layer counted faults of the others");
    wait_until(|| fails.writer_stats().faults > 10 && panics.writer_stats().faults > 10, "faults counted each period");

    misbehave.store(false, Ordering::Relaxed);
    for reader in [&fails, &panics, &hangs] {
        wait_for_state(reader, WriterState::Running, "recovery");
    }
    handler.stop();
    assert_eq!(good.writer_state(), WriterState::Gone);
    assert!(dir.files().is_empty(), "channels left: {:?}", dir.files());
}

/// Waits (at most 20 s, for a loaded machine) until `done`.
fn wait_until(done: impl Fn() -> bool, what: &str) {
    let started = std::time::Instant::now();
    while !done() {
        assert!(started.elapsed() < Duration::from_secs(20), "never happened: {what}");
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// Waits until `reader`'s writer is in `state`, after `why`.
fn wait_for_state(reader: &Reader, state: WriterState, why: &str) {
    wait_until(|| reader.writer_state() == state, &format!("{} {state:?} after {why}", reader.label()));
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
    // Each start follows a stop in this process, while other tests of this
    // binary spawn children (who hold copies of the stopped writer's name
    // lock until their exec): the new writer waits for those, it is not Busy.
    DriverHandler::start("skin", Box::new(make(12)), &keep).unwrap().stop();
    // Same topology, then a changed one: each is a new channel under the name.
    DriverHandler::start("skin", Box::new(make(12)), &keep).unwrap().stop();
    let handler = DriverHandler::start("skin", Box::new(make(24)), &keep).unwrap();
    let reader = skinware::Reader::open_with("skin", "arm", &dir.reader()).unwrap();
    assert_eq!((reader.topology().unwrap().frame_bytes() / 2, reader.writer_generation()), (24, 3));
    handler.stop();
}
