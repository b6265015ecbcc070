//! The CAN skin driver: one layer fed by one bus, in one of the skins'
//! protocols. A bus thread receives frames, decodes them and keeps the newest
//! value of every taxel with the time its module was last complete; each
//! acquisition copies that image, or fails (faulting the layer) when the link
//! is lost or a module has not been complete for 1.5 periods. The bus thread
//! reopens a lost link on its own, with backoff, and sends the protocol's
//! start-up commands again.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use skinware::driver::{Driver, DriverError, LayerSource, LayerSpec};
use skinware::{FrameWriter, LayerTopology, RtOptions, TopologyBuilder, TopologyError};

use super::icub_mtb::{self, Board, BoardSettings, Message};
use super::{BusError, CanBus, CanFrame, cyskin, xela};

/// Which protocol the bus speaks, with its settings.
#[derive(Clone, Debug, PartialEq)]
pub enum Protocol {
    /// iCub MTB boards.
    IcubMtb {
        /// The boards and their triangles, in layer order.
        boards: Vec<Board>,
        /// What the host configures them with.
        settings: BoardSettings,
    },
    /// CySkin CPM patches, by the identifier of each one's first frame.
    CySkin {
        /// One base identifier per patch, in layer order.
        base_ids: Vec<u16>,
    },
    /// A XELA uSkin board, polled once per acquisition.
    Xela {
        /// Its address.
        board: u8,
        /// Its taxels (16 on a 4×4 board).
        taxels: usize,
    },
}

/// A CAN skin driver's settings.
#[derive(Clone, Debug)]
pub struct CanDriverConfig {
    /// Driver name, for logs.
    pub name: String,
    /// The layer (channel) it publishes.
    pub layer: String,
    /// The bus URL (`slcan:///dev/ttyACM0?bitrate=1000000`, …).
    pub interface: String,
    /// The protocol.
    pub protocol: Protocol,
    /// Acquisitions per second.
    pub rate_hz: f64,
    /// Real-time settings of the layer's writer thread.
    pub rt: RtOptions,
}

/// What is wrong with a CAN driver's settings; each message names the
/// setting and the fix.
#[derive(Debug, thiserror::Error)]
pub enum CanConfigError {
    /// The rate is not a positive number.
    #[error("rate {rate_hz} Hz: give a positive rate")]
    Rate {
        /// The rate given.
        rate_hz: f64,
    },
    /// The bus URL cannot be understood.
    #[error(transparent)]
    Interface(#[from] BusError),
    /// An iCub layer without boards.
    #[error("no boards: list at least one `[[driver.board]]` with its address and triangles")]
    NoBoards,
    /// An MTB board address outside 1..=15.
    #[error("board address {address} is not 1 to 15")]
    BoardAddress {
        /// The address given.
        address: u8,
    },
    /// An MTB triangle outside 0..=15.
    #[error("board {board}: triangle {triangle} is not 0 to 15")]
    Triangle {
        /// The board's address.
        board: u8,
        /// The triangle given.
        triangle: u8,
    },
    /// A CySkin patch whose four frames would not fit below 0x800.
    #[error("CySkin base identifier {base:#x} leaves no room for its 4 frames below 0x800")]
    CySkinBase {
        /// The base identifier given.
        base: u16,
    },
    /// A XELA board with no taxels or too many.
    #[error("a XELA board has 1 to {max} taxels, not {taxels}", max = xela::MAX_TAXELS)]
    XelaTaxels {
        /// The taxels given.
        taxels: usize,
    },
    /// The layer's topology was refused.
    #[error(transparent)]
    Topology(#[from] TopologyError),
}

/// A module is stale once it has not been complete for this many periods.
const STALE_PERIODS: f64 = 1.5;

/// After the start, how long boards may take to send their first complete
/// frame before their silence is a fault. Until then the layer publishes
/// nothing and counts no fault: boards being configured are not a fault, and
/// a fault counted (and logged) at every start would teach people to ignore
/// them. (Nor are their frames partial: a module never heard from has no
/// previous response to repeat.)
const FIRST_FRAME_GRACE_NS: u64 = 1_000_000_000;
const RECEIVE_SLICE: Duration = Duration::from_millis(5);
const MAX_BACKOFF: Duration = Duration::from_secs(2);
/// A bus without a frame this long has its devices configured again.
const RESTART_AFTER_QUIET: Duration = Duration::from_millis(500);

impl CanDriverConfig {
    /// The layer's topology: MTB boards are patches and triangles modules;
    /// CySkin patches are patches of one 16-taxel module; a XELA board is a
    /// patch whose taxels are modules of three sensors (X, Y, Z).
    pub fn topology(&self) -> Result<LayerTopology, CanConfigError> {
        let mut builder = TopologyBuilder::new(&self.layer, "pressure", self.rate_hz);
        match &self.protocol {
            Protocol::IcubMtb { boards, .. } => {
                if boards.is_empty() {
                    return Err(CanConfigError::NoBoards);
                }
                for board in boards {
                    if !(1..=15).contains(&board.address) {
                        return Err(CanConfigError::BoardAddress { address: board.address });
                    }
                    builder.patch(u32::from(board.address));
                    for &triangle in &board.triangles {
                        if triangle > 15 {
                            return Err(CanConfigError::Triangle { board: board.address, triangle });
                        }
                        let base = u32::from(board.address) << 8 | u32::from(triangle) << 4;
                        builder.module(u32::from(board.address) << 4 | u32::from(triangle), (0..12).map(|k| base | k));
                    }
                }
            }
            Protocol::CySkin { base_ids } => {
                for (i, &base) in base_ids.iter().enumerate() {
                    if base > 0x7F9 {
                        return Err(CanConfigError::CySkinBase { base });
                    }
                    builder.patch(i as u32 + 1);
                    builder.module(u32::from(base), (0..cyskin::TAXELS as u32).map(|t| u32::from(base) << 4 | t));
                }
            }
            Protocol::Xela { board, taxels } => {
                if *taxels == 0 || *taxels > xela::MAX_TAXELS {
                    return Err(CanConfigError::XelaTaxels { taxels: *taxels });
                }
                builder.patch(u32::from(*board));
                for taxel in 0..*taxels as u32 {
                    builder.module(taxel, (0..xela::AXES as u32).map(|axis| taxel << 2 | axis));
                }
            }
        }
        Ok(builder.build()?)
    }
}

/// The newest image of the layer, written by the bus thread.
struct Image {
    values: Vec<u16>,
    /// When each module was last complete, CLOCK_MONOTONIC ns (`None`: never).
    complete_at: Vec<Option<u64>>,
    /// A module's own error report (an MTB tail's error nibble), if any.
    module_error: Vec<u8>,
    /// Why the link is down, while it is.
    link_down: Option<String>,
}

/// The CAN skin driver.
pub struct CanDriver {
    config: CanDriverConfig,
    topology: LayerTopology,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl CanDriver {
    /// Checks the settings and builds the topology; nothing is opened yet.
    pub fn new(config: CanDriverConfig) -> Result<CanDriver, CanConfigError> {
        if !(config.rate_hz.is_finite() && config.rate_hz > 0.0) {
            return Err(CanConfigError::Rate { rate_hz: config.rate_hz });
        }
        super::bus::BusUrl::parse(&config.interface)?;
        let topology = config.topology()?;
        Ok(CanDriver { config, topology, stop: Arc::new(AtomicBool::new(false)), thread: None })
    }
}

impl Driver for CanDriver {
    fn name(&self) -> &str {
        &self.config.name
    }

    fn layers(&self) -> Vec<LayerSpec> {
        vec![LayerSpec { topology: self.topology.clone(), rt: self.config.rt.clone() }]
    }

    fn start(&mut self) -> Result<Vec<Box<dyn LayerSource>>, DriverError> {
        let bus = super::open(&self.config.interface)?;
        let modules = self.topology.modules.len();
        let image = Arc::new(Mutex::new(Image {
            values: vec![0; self.topology.sensors.len()],
            complete_at: vec![None; modules],
            module_error: vec![0; modules],
            link_down: None,
        }));
        self.stop.store(false, Ordering::Relaxed);
        let mut link = Link {
            bus: Some(bus),
            config: self.config.clone(),
            image: image.clone(),
            stop: self.stop.clone(),
            decoder: Decoder::new(&self.config.protocol, &self.topology),
        };
        link.start_devices();
        self.thread = Some(
            std::thread::Builder::new()
                .name(format!("can-{}", self.config.layer))
                .spawn(move || link.run())
                .map_err(|e| format!("cannot start the bus thread: {e}"))?,
        );
        let period = Duration::from_secs_f64(1.0 / self.config.rate_hz);
        Ok(vec![Box::new(CanLayer {
            image,
            topology: self.topology.clone(),
            stale_after: period.mul_f64(STALE_PERIODS),
            first_acquired_ns: None,
        })])
    }

    fn stop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// Turns frames into taxel values for the image.
struct Decoder {
    protocol: Protocol,
    /// MTB: (board, triangle) → module index; pending heads per module.
    mtb_modules: std::collections::HashMap<(u8, u8), usize>,
    pending_heads: Vec<Option<[u8; 7]>>,
    /// CySkin: quarters seen of the current sample, per patch.
    cyskin_samples: Vec<([u16; cyskin::TAXELS], u8)>,
}

impl Decoder {
    fn new(protocol: &Protocol, topology: &LayerTopology) -> Decoder {
        let mut mtb_modules = std::collections::HashMap::new();
        if let Protocol::IcubMtb { .. } = protocol {
            for (index, module) in topology.modules.iter().enumerate() {
                mtb_modules.insert(((module.id >> 4) as u8, (module.id & 0xF) as u8), index);
            }
        }
        let cyskin_patches = if let Protocol::CySkin { base_ids } = protocol { base_ids.len() } else { 0 };
        Decoder {
            protocol: protocol.clone(),
            mtb_modules,
            pending_heads: vec![None; topology.modules.len()],
            cyskin_samples: vec![([0; cyskin::TAXELS], 0); cyskin_patches],
        }
    }

    /// Applies one frame to the image.
    fn apply(&mut self, frame: &CanFrame, image: &mut Image, topology_modules: &[std::ops::Range<usize>]) {
        let now = skinware::os::monotonic_ns();
        match &self.protocol {
            Protocol::IcubMtb { settings: _, .. } => match icub_mtb::parse(frame) {
                Message::Head { board, triangle, raw } => {
                    if let Some(&module) = self.mtb_modules.get(&(board, triangle)) {
                        self.pending_heads[module] = Some(raw);
                    }
                }
                Message::Tail { board, triangle, raw, error, .. } => {
                    let Some(&module) = self.mtb_modules.get(&(board, triangle)) else { return };
                    // A tail without its head completes nothing.
                    let Some(head) = self.pending_heads[module].take() else { return };
                    let range = topology_modules[module].clone();
                    for (value, raw) in image.values[range].iter_mut().zip(head.iter().chain(raw.iter())) {
                        *value = icub_mtb::response(*raw);
                    }
                    image.module_error[module] = error;
                    image.complete_at[module] = Some(now);
                }
                Message::Command { .. } | Message::Other => {}
            },
            Protocol::CySkin { base_ids } => {
                for (patch, &base) in base_ids.iter().enumerate() {
                    let Some(quarter) = cyskin::parse(frame, base) else { continue };
                    let (taxels, seen) = &mut self.cyskin_samples[patch];
                    cyskin::place(&quarter, taxels);
                    *seen |= 1 << quarter.index;
                    if quarter.index == cyskin::FRAMES - 1 {
                        if *seen == 0b1111 {
                            image.values[topology_modules[patch].clone()].copy_from_slice(taxels);
                            image.complete_at[patch] = Some(now);
                        }
                        *seen = 0;
                    }
                }
            }
            Protocol::Xela { .. } => {
                if let Some(reading) = xela::parse(frame)
                    && let Some(range) = topology_modules.get(reading.taxel)
                {
                    match reading.axes {
                        Some(axes) => {
                            image.values[range.clone()].copy_from_slice(&axes);
                            image.module_error[reading.taxel] = 0;
                        }
                        None => image.module_error[reading.taxel] = 1,
                    }
                    image.complete_at[reading.taxel] = Some(now);
                }
            }
        }
    }
}

/// The bus thread's state.
struct Link {
    bus: Option<Box<dyn CanBus>>,
    config: CanDriverConfig,
    image: Arc<Mutex<Image>>,
    stop: Arc<AtomicBool>,
    decoder: Decoder,
}

impl Link {
    /// Sends what the devices need to start streaming.
    fn start_devices(&mut self) {
        let Some(bus) = &mut self.bus else { return };
        if let Protocol::IcubMtb { boards, settings } = &self.config.protocol {
            for frame in icub_mtb::start_commands(boards, settings) {
                if let Err(e) = bus.send(&frame) {
                    tracing::warn!(url = %bus.url(), error = %e, "cannot send a start-up command");
                }
            }
        }
    }

    fn run(mut self) {
        // The bus thread is part of the acquisition: it runs with the
        // layer's real-time settings, so that frames are taken off the bus
        // as punctually as they are published.
        for refused in self.config.rt.apply() {
            tracing::warn!(url = %self.config.interface, "bus thread: {refused}");
        }
        let topology_modules: Vec<std::ops::Range<usize>> = match self.config.topology() {
            Ok(topology) => topology.modules.iter().map(|m| m.sensors.clone()).collect(),
            Err(_) => return,
        };
        let period = Duration::from_secs_f64(1.0 / self.config.rate_hz);
        let mut next_poll = Instant::now();
        let mut backoff = Duration::from_millis(100);
        // A bus that has gone quiet may have devices that restarted (power
        // cycled, or an emulator restarted) and wait to be configured again.
        let mut last_frame = Instant::now();
        let mut last_restart = Instant::now();
        while !self.stop.load(Ordering::Relaxed) {
            let Some(bus) = &mut self.bus else {
                std::thread::sleep(backoff);
                match super::open(&self.config.interface) {
                    Ok(bus) => {
                        tracing::info!(url = %self.config.interface, "bus reopened");
                        self.bus = Some(bus);
                        backoff = Duration::from_millis(100);
                        self.start_devices();
                    }
                    Err(e) => {
                        self.set_link_down(e.to_string());
                        backoff = (backoff * 2).min(MAX_BACKOFF);
                    }
                }
                continue;
            };
            if let Protocol::Xela { board, .. } = self.config.protocol
                && Instant::now() >= next_poll
            {
                next_poll += period;
                if let Err(e) = bus.send(&xela::request(board)) {
                    self.lose(e);
                    continue;
                }
            }
            let quiet = last_frame.elapsed();
            if quiet > RESTART_AFTER_QUIET && last_restart.elapsed() > RESTART_AFTER_QUIET {
                tracing::info!(url = %self.config.interface, quiet_ms = quiet.as_millis() as u64, "bus quiet; configuring the devices again");
                last_restart = Instant::now();
                self.start_devices();
                continue;
            }
            match bus.receive(RECEIVE_SLICE) {
                Ok(Some(frame)) => {
                    last_frame = Instant::now();
                    let mut image = skinware::lock(&self.image);
                    image.link_down = None;
                    self.decoder.apply(&frame, &mut image, &topology_modules);
                }
                Ok(None) => {}
                Err(e) => self.lose(e),
            }
        }
        if let (Some(bus), Protocol::IcubMtb { boards, .. }) = (&mut self.bus, &self.config.protocol) {
            for frame in icub_mtb::stop_commands(boards) {
                let _ = bus.send(&frame);
            }
        }
    }

    fn lose(&mut self, error: BusError) {
        tracing::warn!(url = %self.config.interface, error = %error, "bus lost; reopening");
        self.set_link_down(error.to_string());
        self.bus = None;
    }

    fn set_link_down(&self, why: String) {
        skinware::lock(&self.image).link_down = Some(why);
    }
}

/// The layer's acquisition: a copy of the newest complete image.
struct CanLayer {
    image: Arc<Mutex<Image>>,
    topology: LayerTopology,
    stale_after: Duration,
    /// When the first acquisition ran: the start of the first-frame grace.
    first_acquired_ns: Option<u64>,
}

impl LayerSource for CanLayer {
    fn acquire(&mut self, frame: &mut FrameWriter<'_>) -> Result<(), DriverError> {
        let image = skinware::lock(&self.image);
        if let Some(why) = &image.link_down {
            return Err(why.clone().into());
        }
        let now = skinware::os::monotonic_ns();
        let since_start = now.saturating_sub(*self.first_acquired_ns.get_or_insert(now));
        let stale_after = self.stale_after.as_nanos() as u64;
        let mut oldest = now;
        let mut not_yet_heard = false;
        for (index, module) in self.topology.modules.iter().enumerate() {
            let patch = self.topology.patches[module.patch].id;
            match image.complete_at[index] {
                None if since_start < FIRST_FRAME_GRACE_NS => not_yet_heard = true,
                None => {
                    return Err(format!(
                        "patch {patch}, module {:#x}: no complete frame in the {} ms since the start (is the board powered, and is its address in the config right?)",
                        module.id,
                        since_start / 1_000_000
                    )
                    .into());
                }
                Some(at) if now.saturating_sub(at) > stale_after => {
                    return Err(format!(
                        "patch {patch}, module {:#x}: no complete frame for {} ms (silent, or a frame of it lost)",
                        module.id,
                        now.saturating_sub(at) / 1_000_000
                    )
                    .into());
                }
                Some(at) => oldest = oldest.min(at),
            }
            if image.module_error[index] != 0 {
                return Err(format!(
                    "patch {patch}, module {:#x}: the device reports error {}",
                    module.id, image.module_error[index]
                )
                .into());
            }
        }
        if not_yet_heard {
            frame.withhold();
            return Ok(());
        }
        frame.write_responses(0, &image.values)?;
        // The frame's acquisition time is when its oldest data arrived.
        frame.set_acquired_ns(oldest);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mtb(boards: Vec<Board>) -> CanDriverConfig {
        CanDriverConfig {
            name: "can".into(),
            layer: "skin".into(),
            interface: "slcan:///dev/null".into(),
            protocol: Protocol::IcubMtb { boards, settings: BoardSettings::default() },
            rate_hz: 50.0,
            rt: RtOptions::default(),
        }
    }

    #[test]
    fn mtb_topology_is_boards_and_triangles() {
        let config = mtb(vec![Board { address: 1, triangles: vec![0, 1] }, Board { address: 3, triangles: vec![7] }]);
        let topology = config.topology().unwrap();
        assert_eq!(topology.patches.iter().map(|p| p.id).collect::<Vec<_>>(), [1, 3]);
        assert_eq!(topology.modules.iter().map(|m| m.id).collect::<Vec<_>>(), [0x10, 0x11, 0x37]);
        assert_eq!(topology.sensors.len(), 3 * icub_mtb::TAXELS_PER_TRIANGLE);
        assert_eq!(topology.sensors[35].uid, 0x37B);
    }

    #[test]
    fn bad_settings_are_explained() {
        assert!(mtb(vec![]).topology().unwrap_err().to_string().contains("no boards"));
        assert!(
            mtb(vec![Board { address: 16, triangles: vec![0] }])
                .topology()
                .unwrap_err()
                .to_string()
                .contains("1 to 15")
        );
        assert!(
            mtb(vec![Board { address: 1, triangles: vec![16] }])
                .topology()
                .unwrap_err()
                .to_string()
                .contains("0 to 15")
        );
        let bad_url =
            CanDriverConfig { interface: "ttyACM0".into(), ..mtb(vec![Board { address: 1, triangles: vec![0] }]) };
        assert!(CanDriver::new(bad_url).err().unwrap().to_string().contains("scheme"));
    }

    /// Boards being configured at a start are not a fault: until the first
    /// complete frame of every module, or the grace's end, nothing is
    /// published (a module never heard from has no response to give).
    #[test]
    fn modules_not_yet_heard_from_are_withheld_within_the_grace_then_a_fault() {
        let config = mtb(vec![Board { address: 1, triangles: vec![0, 1] }]);
        let topology = config.topology().unwrap();
        let dir = std::env::temp_dir().join(format!("skinware-can-grace-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let options = skinware::WriterOptions { dir: Some(dir.clone()), ..skinware::WriterOptions::default() };
        let mut writer = skinware::Writer::create("can", "skin", topology.frame_bytes(), b"", &options).unwrap();
        let now = skinware::os::monotonic_ns();
        let image = Image {
            values: vec![7; topology.sensors.len()],
            complete_at: vec![Some(now), None],
            module_error: vec![0; 2],
            link_down: None,
        };
        let mut layer = CanLayer {
            image: Arc::new(Mutex::new(image)),
            topology,
            stale_after: Duration::from_secs(3600),
            // Started "in the future": inside the grace however slow this run is.
            first_acquired_ns: Some(u64::MAX),
        };
        let mut frame = writer.begin();
        layer.acquire(&mut frame).expect("a module not yet heard from within the grace is no fault");
        assert!(frame.is_withheld(), "a frame with a module never heard from was to be published");

        layer.first_acquired_ns = Some(now.saturating_sub(2 * FIRST_FRAME_GRACE_NS));
        let mut frame = writer.begin();
        let error = layer.acquire(&mut frame).unwrap_err().to_string();
        assert!(
            error.contains("module 0x11: no complete frame in the") && error.contains("since the start"),
            "{error}"
        );

        // Once every module was heard from, frames are published.
        skinware::lock(&layer.image).complete_at[1] = Some(skinware::os::monotonic_ns());
        let mut frame = writer.begin();
        layer.acquire(&mut frame).unwrap();
        assert!(!frame.is_withheld());
        drop(writer);
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_triangle_is_complete_only_with_head_and_tail() {
        let config = mtb(vec![Board { address: 2, triangles: vec![5] }]);
        let topology = config.topology().unwrap();
        let modules: Vec<_> = topology.modules.iter().map(|m| m.sensors.clone()).collect();
        let mut decoder = Decoder::new(&config.protocol, &topology);
        let mut image = Image { values: vec![0; 12], complete_at: vec![None], module_error: vec![0], link_down: None };
        let raw: [u8; 12] = std::array::from_fn(|k| 240 - k as u8);
        let [head, tail] = icub_mtb::triangle_frames(2, 5, &raw, 0, 0);
        decoder.apply(&tail, &mut image, &modules);
        assert!(image.complete_at[0].is_none(), "a tail alone");
        decoder.apply(&head, &mut image, &modules);
        assert!(image.complete_at[0].is_none(), "a head alone");
        decoder.apply(&tail, &mut image, &modules);
        assert!(image.complete_at[0].is_some());
        assert_eq!(image.values, (0..12).map(|k| 15 + k).collect::<Vec<u16>>());
    }
}
