//! `skin view` of the iCub skin of `examples/icub-can.toml` (two CAN buses
//! of 8-bit MTB boards, emulated: `skin run` starts its `[[emulator]]`s) in
//! headless Chromium. The viewer starts first, with the skin's geometry
//! published and its layers not yet there: the page labels the map's
//! pieces and shows the layers connecting, not gone. Then the skin starts
//! (running, never shown gone before), its touches show in colour (its
//! responses rest at 15 and reach 255: the range learnt from them, not the
//! 16-bit one), the colour range control changes the scale, and the page
//! says so plainly when the skin stops and when the viewer does.

use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use skinware_geometry::{Calibration, SkinGeometry};

use super::*;
use crate::util::{interrupt_and_wait, one_skin_at_a_time};

/// The skin of `examples/icub-can.toml`.
const SKIN: &str = "icub";
/// Its layers, one per bus.
const LAYERS: [&str; 2] = ["torso", "arm"];

/// The example's skin in its own segment directory, its buses' links in it
/// too; `skin run` of it and `skin view` of it are started by the test.
/// Both are stopped (and the directory removed) when dropped, even if the
/// test failed.
struct Icub {
    dir: PathBuf,
    config: PathBuf,
    run: Option<Child>,
    view: Option<Child>,
}

impl Icub {
    /// Writes the example's configuration with its buses' links in `dir`,
    /// and publishes its geometry, as `skin run` does before its drivers
    /// create their channels.
    fn prepare() -> Icub {
        let dir = PathBuf::from("/dev/shm").join(format!("skin-browser-icub-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let example = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../examples/icub-can.toml");
        let text = std::fs::read_to_string(&example).unwrap();
        assert!(text.contains("/tmp/skinware-icub-bus0"), "the example's links moved: update this test");
        let config = dir.join("icub-can.toml");
        std::fs::write(&config, text.replace("/tmp/skinware-icub-", &format!("{}/", dir.display()))).unwrap();
        let icub = Icub { dir, config, run: None, view: None };
        icub.publish_geometry();
        icub
    }

    /// The geometry `skin run` publishes for the configuration (the CAN
    /// drivers' own flat layout, each layer its own link).
    fn publish_geometry(&self) {
        let config = skin::config::Config::load(&self.config).unwrap();
        assert_eq!(config.skin, SKIN);
        let (mut layers, mut calibration) = (Vec::new(), Calibration::new());
        for (index, driver) in config.drivers.iter().enumerate() {
            let built = driver.build(&config.skin).unwrap();
            let own = built.calibration(index);
            for spec in built.layers() {
                let topology = spec.topology;
                for sensor in &topology.sensors {
                    let entry = own.get(&topology.name, &topology.sensor_type, sensor.uid).unwrap();
                    calibration.insert(&topology.name, sensor.uid, entry.clone()).unwrap();
                }
                layers.push(topology);
            }
        }
        SkinGeometry::build(SKIN, &layers, &calibration, &[]).unwrap().publish(&self.dir).unwrap();
    }

    fn skin_command(&self) -> Command {
        let mut command = Command::new(env!("CARGO_BIN_EXE_skin"));
        command.env("SKINWARE_SHM_DIR", &self.dir).env("RUST_LOG", "error").stdout(Stdio::null());
        command
    }

    /// `skin view` of the skin; returns its URL once it accepts browsers.
    fn start_view(&mut self) -> String {
        let port = free_port();
        let listen = format!("127.0.0.1:{port}");
        self.view = Some(self.skin_command().args(["view", "--skin", SKIN, "--listen", &listen]).spawn().unwrap());
        wait_for("skin view to listen", Duration::from_secs(30), || TcpStream::connect(&listen).ok());
        format!("http://{listen}/")
    }

    /// `skin run` of the configuration: its emulated boards and drivers.
    fn start_skin(&mut self) {
        self.run = Some(self.skin_command().arg("run").arg(&self.config).spawn().unwrap());
    }

    /// Ctrl-C to `skin run`, which stops its drivers and removes the channels.
    fn stop_skin(&mut self) {
        let mut run = self.run.take().unwrap();
        let status = interrupt_and_wait(&mut run, "skin run", Duration::from_secs(30));
        assert!(status.success(), "skin run exited with {status} on SIGINT");
    }

    /// Ctrl-C to `skin view`.
    fn stop_view(&mut self) {
        let mut view = self.view.take().unwrap();
        let status = interrupt_and_wait(&mut view, "skin view", Duration::from_secs(15));
        assert!(status.success(), "skin view exited with {status} on SIGINT");
    }
}

impl Drop for Icub {
    fn drop(&mut self) {
        for mut child in [self.run.take(), self.view.take()].into_iter().flatten() {
            // SIGTERM first, so that the supervisor stops its drivers and emulators.
            send_signal(child.id(), rustix::process::Signal::TERM);
            if wait_for_exit(&mut child, Duration::from_secs(15)).is_none() {
                let _ = child.kill();
                let _ = child.wait();
            }
        }
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

#[test]
fn icub_skin_in_headless_chromium() {
    let Some(programs) = browser_programs("icub_skin_in_headless_chromium") else {
        return;
    };
    let _alone = one_skin_at_a_time();
    let mut icub = Icub::prepare();
    let url = icub.start_view();
    let browser = Browser::start(&programs);
    browser.open(&url);

    before_the_skin_runs_its_layers_are_connecting(&browser);
    let started = Instant::now();
    icub.start_skin();
    wait_for("both layers running", Duration::from_secs(60), || {
        LAYERS.iter().all(|layer| layer_state(&browser, layer).0 == "running").then_some(())
    });
    println!("browser: the iCub skin's layers show running {} ms after `skin run`", started.elapsed().as_millis());
    for (index, layer) in LAYERS.iter().enumerate() {
        let seen = states_seen(&browser, index);
        assert!(!seen.iter().any(|state| state == "gone"), "{layer} was shown gone before it ran: {seen:?}");
    }
    its_touches_show_in_colour(&browser);
    the_colour_range_control_changes_the_scale(&browser);

    icub.stop_skin();
    the_page_says_the_skin_stopped(&browser);
    icub.stop_view();
    let said = wait_for("the page to say its server is gone", Duration::from_secs(10), || {
        banner(&browser).filter(|text| text.contains("server is gone"))
    });
    println!("browser: after `skin view` stopped the page says: {said}");
}

/// Step 1: The geometry is there, the channels are not: the map is drawn and
/// labelled, and the layers are connecting, however long it takes.
fn before_the_skin_runs_its_layers_are_connecting(browser: &Browser) {
    wait_for("the geometry", Duration::from_secs(30), || {
        (browser.run(STATS_PROBE)["geometryBytes"].as_u64()? > 0).then_some(())
    });
    let labels = piece_labels(browser);
    println!("browser: the iCub map's labels: {labels:?}");
    for layer in LAYERS {
        assert!(labels.iter().any(|label| label == layer), "no label {layer:?} over the map: {labels:?}");
    }
    std::thread::sleep(Duration::from_secs(1));
    for layer in LAYERS {
        assert_eq!(layer_state(browser, layer), ("connecting".into(), "connecting".into()), "{layer}");
        assert!(rate_cells(browser, layer).iter().all(|cell| cell.is_empty() || cell == "\u{2014}"));
    }
    assert_eq!(banner(browser), None, "a skin not started yet is not a stopped one");
}

/// Step 2: An 8-bit skin's touches show in colour: full colour at the range
/// learnt from its responses (at most 255 above its resting 15), not at the
/// 20,000 of a 16-bit skin.
fn its_touches_show_in_colour(browser: &Browser) {
    let lit = wait_for("touches drawn in colour", Duration::from_secs(30), || {
        Some(browser.run(CANVAS_PROBE)["lit"].as_u64()?).filter(|&lit| lit > 40)
    });
    let auto = wait_for("the learnt range of a touched skin", Duration::from_secs(10), || {
        let scales = browser.run(STATS_PROBE)["autoScales"].clone();
        Some(scales[0].as_u64()?).filter(|&scale| scale > 31)
    });
    println!("browser: the iCub skin: {lit} lit pixels, full colour at {auto} above baseline (auto)");
    assert!(auto <= 255, "an 8-bit skin's learnt full scale is {auto}");
    let legend = browser.run("return document.getElementById('scale-max').textContent;");
    assert!(legend.as_str().is_some_and(|text| text.parse::<u64>().is_ok_and(|v| v <= 255)), "legend {legend}");
    // For the screenshot (not a check: a loaded machine may stall the
    // emulated boards for a moment), rates measured over a whole window.
    let deadline = Instant::now() + Duration::from_secs(10);
    while Instant::now() < deadline
        && !LAYERS.iter().all(|layer| rate_cells(browser, layer)[1].parse::<f64>().is_ok_and(|rate| rate > 0.0))
    {
        std::thread::sleep(Duration::from_millis(200));
    }
    browser.screenshot("viewer-icub.png");
}

/// Step 3: In on-request mode (frames that stay still), a wide range typed
/// in darkens the touches; "auto" brings them back.
fn the_colour_range_control_changes_the_scale(browser: &Browser) {
    choose_mode(browser, "request", 10.0);
    wait_for("requested frames with a touch on them", Duration::from_secs(30), || {
        let asked = seqs(browser);
        browser.run("document.getElementById('request').click();");
        wait_for("both layers to answer the request", Duration::from_secs(5), || {
            seqs(browser).iter().zip(&asked).all(|(new, old)| new > old).then_some(())
        });
        (browser.run(CANVAS_PROBE)["lit"].as_u64()? > 40).then_some(())
    });
    let [lit_auto, lit_wide, lit_back] = lit_at_scales(browser, "pressure", 65535);
    println!(
        "browser: the iCub skin's still frames: {lit_auto} lit pixels at auto, {lit_wide} at 65,535, {lit_back} back at auto"
    );
    assert!(lit_wide * 4 < lit_auto, "a 16-bit range must darken an 8-bit skin's touches: {lit_wide} vs {lit_auto}");
    assert!(lit_back.abs_diff(lit_auto) * 10 <= lit_auto, "auto again: {lit_back} vs {lit_auto}");
    choose_mode(browser, "asap", 10.0);
    // The new mode's readers have read both layers (a layer whose channel
    // goes before its reader opens it stays connecting, not gone).
    wait_for("both layers running in asap mode", Duration::from_secs(10), || {
        LAYERS.iter().all(|layer| layer_state(browser, layer).0 == "running").then_some(())
    });
}

/// Step 4: `skin run` stopped: the page says the skin has stopped, shows
/// every layer gone and no rates.
fn the_page_says_the_skin_stopped(browser: &Browser) {
    let said = wait_for("the page to say the skin stopped", Duration::from_secs(15), || {
        banner(browser).filter(|text| text.contains("skin has stopped"))
    });
    println!("browser: after `skin run` stopped the page says: {said}");
    for layer in LAYERS {
        assert_eq!(layer_state(browser, layer).0, "gone", "{layer}");
        wait_for("the rates to be cleared", Duration::from_secs(5), || {
            rate_cells(browser, layer).iter().all(|cell| cell == "\u{2014}").then_some(())
        });
    }
    let stats = browser.run(STATS_PROBE);
    assert_eq!(stats["skinState"], "stopped");
    assert_eq!((stats["markers"].as_u64(), stats["arrows"].as_u64()), (Some(0), Some(0)));
}
