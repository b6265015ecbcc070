//! `[[driver]]` tables: the virtual skin's, the CAN driver's and the EtherCAT
//! driver's parameters, and the driver they build.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use serde::Deserialize;
use skinware::driver::{Driver, LayerSpec};
use skinware_drivers::can::driver::{CanDriver, CanDriverConfig, Protocol};
use skinware_drivers::can::icub_mtb::{Board, BoardSettings};
use skinware_drivers::ethercat::{EthercatDriver, EthercatDriverConfig, FrameLink, SegmentConfig};
use skinware_drivers::{CablePull, Rate, ScriptedContact, VirtualSkin, VirtualSkinConfig};
use skinware_geometry::{Calibration, SensorCalibration};

use super::process::{RestartConfig, RtConfig};
use super::topology::LayerConfig;

/// The kinds of driver.
#[derive(Debug, Deserialize, Clone, Copy, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum DriverKind {
    /// The virtual skin.
    Virtual,
    /// A real skin on a CAN bus.
    Can,
    /// A recording (`skin record`), replayed at its recorded times.
    Replay,
    /// Tactile segments on EtherCAT (one SubDevice each).
    Ethercat,
    /// A ROS 2 topic (DDS): a sensor's own ROS 2 driver, or a simulator.
    Ros2,
}

impl DriverKind {
    /// Every kind, in the order the docs list them.
    pub const ALL: [DriverKind; 5] =
        [DriverKind::Virtual, DriverKind::Can, DriverKind::Ethercat, DriverKind::Ros2, DriverKind::Replay];

    /// Its name in a config (`kind = "virtual"`) and in a driver's status.
    pub fn as_str(self) -> &'static str {
        match self {
            DriverKind::Virtual => "virtual",
            DriverKind::Can => "can",
            DriverKind::Replay => "replay",
            DriverKind::Ethercat => "ethercat",
            DriverKind::Ros2 => "ros2",
        }
    }

    /// The kind called `name` ([`as_str`](Self::as_str)), if there is one.
    pub fn from_name(name: &str) -> Option<DriverKind> {
        DriverKind::ALL.into_iter().find(|kind| kind.as_str() == name)
    }

    /// Whether its layers have a simulated cable that `skin pull` can pull
    /// ([`pull_file`]): only the virtual skin's. A real bus's cable is pulled
    /// by hand, and a replay plays back whatever faults it recorded.
    pub fn has_simulated_cables(self) -> bool {
        self == DriverKind::Virtual
    }
}

/// The protocols of `kind = "can"`.
#[derive(Debug, Deserialize, Clone, Copy, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum CanProtocol {
    /// iCub MTB boards.
    IcubMtb,
    /// CySkin CPM patches.
    Cyskin,
    /// A XELA uSkin board.
    Xela,
}

/// An MTB board's triangles: a count (0..n) or a list.
#[derive(Debug, Deserialize, Clone)]
#[serde(untagged)]
pub enum Triangles {
    /// Triangles 0 to n-1.
    Count(u8),
    /// These triangles.
    List(Vec<u8>),
}

/// One `[[driver.board]]` table (MTB).
#[derive(Debug, Deserialize, Clone)]
#[serde(deny_unknown_fields)]
pub struct BoardConfig {
    /// The board's CAN address.
    pub address: u8,
    /// Its triangles.
    pub triangles: Triangles,
}

/// One `[[driver.segment]]` table (EtherCAT): a tactile segment, at its
/// position in ring order.
#[derive(Debug, Deserialize, Clone)]
#[serde(deny_unknown_fields)]
pub struct SegmentTable {
    /// The layer it publishes (default: `DRIVER-POSITION`).
    pub layer: Option<String>,
    /// The vendor ID it must report.
    pub vendor_id: u32,
    /// The product code it must report.
    pub product_code: u32,
    /// Its taxels.
    pub taxels: usize,
    /// Taxels per module, all modules alike (the last may have fewer).
    pub sensors_per_module: Option<usize>,
    /// Taxels of each module, in order (instead of `sensors_per_module`).
    pub modules: Option<Vec<usize>>,
    /// Its patch id (default: position + 1).
    pub patch: Option<u32>,
    /// Ask for baseline-subtracted taxels instead of raw ones.
    #[serde(default)]
    pub baseline: bool,
}

/// One `[[driver]]` table.
#[derive(Debug, Deserialize, Clone)]
#[serde(deny_unknown_fields)]
pub struct DriverConfig {
    /// Unique among the drivers; generated layers are `NAME-0`, `NAME-1`, ...
    pub name: String,
    /// Which driver.
    pub kind: DriverKind,
    /// Real-time settings of its writer threads (`[driver.rt]`).
    #[serde(default)]
    pub rt: RtConfig,
    /// How its process is restarted (`[driver.restart]`).
    #[serde(default)]
    pub restart: RestartConfig,
    /// Frame buffers per layer channel; if not given, enough for each layer
    /// to keep 20 ms of frames readable ([`skinware::slots_for_history`]:
    /// 3 up to 100 Hz, 21 at 1 kHz).
    pub slots: Option<usize>,
    /// Generated skin: total sensors, split equally over `layers`.
    pub sensors: Option<usize>,
    /// Generated skin: number of layers.
    pub layers: Option<usize>,
    /// Generated skin: sensors per module (a layer's last module may have fewer).
    pub sensors_per_module: Option<usize>,
    /// Generated skin: `[min, max]` modules per patch, drawn per patch.
    pub modules_per_patch: Option<[usize; 2]>,
    /// Acquisition rate of each layer, drawn once per layer.
    pub rate_hz: Option<Rate>,
    /// Seed of every random choice (rates, patch sizes, contacts, noise).
    pub seed: Option<u64>,
    /// Scheduled disconnections (`[[driver.cable_pull]]`).
    #[serde(default, rename = "cable_pull")]
    pub cable_pulls: Vec<CablePull>,
    /// Scripted contacts (`[[driver.contact]]`).
    #[serde(default, rename = "contact")]
    pub contacts: Vec<ScriptedContact>,
    /// Whether random contacts press and slide all over the body (default true).
    pub random_contacts: Option<bool>,
    /// Uids of simulated dead taxels (their response never changes).
    #[serde(default)]
    pub dead_taxels: Vec<u32>,
    /// Uids of simulated stuck (saturated) taxels.
    #[serde(default)]
    pub stuck_taxels: Vec<u32>,
    /// Virtual skin: publish a checkable pattern instead of the simulation
    /// (for verifying readers, `skin bench soak`).
    #[serde(default)]
    pub verify_pattern: bool,
    /// A calibration file (skinware or skin.calib format); the virtual skin
    /// calibrates itself when absent.
    pub calibration: Option<PathBuf>,
    /// Layers with an explicit topology (instead of generated ones).
    #[serde(default, rename = "layer")]
    pub explicit_layers: Vec<LayerConfig>,
    // CAN driver parameters.
    /// The bus URL.
    pub interface: Option<String>,
    /// The skin's wire format.
    pub protocol: Option<CanProtocol>,
    /// The layer's name (default: the driver's).
    pub layer_name: Option<String>,
    /// MTB: the boards' streaming period.
    pub period_ms: Option<u8>,
    /// MTB: the raw value of an untouched taxel.
    pub no_load: Option<u8>,
    /// MTB: sensitivity shift.
    pub shift: Option<u8>,
    /// MTB boards (`[[driver.board]]`).
    #[serde(default, rename = "board")]
    pub boards: Vec<BoardConfig>,
    /// CySkin: each patch's first frame identifier.
    #[serde(default)]
    pub base_ids: Vec<u16>,
    /// XELA: the board's address.
    pub address: Option<u8>,
    /// XELA, ROS 2: its taxels.
    pub taxels: Option<usize>,
    // ROS 2 driver parameters (`taxels`, `layer_name`, `rate_hz`,
    // `sensors_per_module` are shared).
    /// The topic to read (`/fingertip/pressure`).
    pub topic: Option<String>,
    /// Its message type: `PointCloud2`, `UInt16MultiArray` or `Float32MultiArray`.
    pub message: Option<String>,
    /// A `PointCloud2`'s field holding the response (default `response`).
    pub field: Option<String>,
    /// The ROS domain (default: `$ROS_DOMAIN_ID`, else 0).
    pub domain: Option<u32>,
    /// Silence longer than this faults the layer (default 500 ms).
    pub timeout_ms: Option<f64>,
    // EtherCAT driver parameters (`interface` is the network interface).
    /// The segments in ring order (`[[driver.segment]]`).
    #[serde(default, rename = "segment")]
    pub segments: Vec<SegmentTable>,
    /// How long a frame may take to come back before it counts as lost (default: one period, at least 1 ms).
    pub frame_timeout_ms: Option<f64>,
    // Replay parameters.
    /// The recording (relative to the config's directory).
    pub file: Option<PathBuf>,
    /// Playback speed (default 1).
    pub speed: Option<f64>,
    /// Start again at the end (default true; else the layers stay, paused, with their last frames).
    #[serde(rename = "loop")]
    pub loop_: Option<bool>,
    /// Start this many seconds into the recording.
    pub from_s: Option<f64>,
    /// Stop this many seconds into the recording.
    pub to_s: Option<f64>,
    /// Replay the recorded services too (default false: the config's services
    /// run live on the replayed layers).
    pub services: Option<bool>,
}

/// A `kind = "replay"` driver: the recording and how to play it.
pub struct ReplayDriver {
    /// The recording.
    pub file: PathBuf,
    /// What its header says (channels, geometry).
    pub header: skinware_record::file::RecordingHeader,
    /// How to play it (the skin and segment directory are set when it starts).
    pub options: skinware_record::ReplayOptions,
}

/// A driver built from its table.
pub enum BuiltDriver {
    /// The virtual skin.
    Virtual(VirtualSkin),
    /// A CAN skin.
    Can(CanDriver),
    /// A replayed recording.
    Replay(Box<ReplayDriver>),
    /// An EtherCAT skin.
    Ethercat(EthercatDriver),
    /// A ROS 2 topic.
    #[cfg(feature = "dds")]
    Ros2(Box<skinware_dds::driver::Ros2Driver>),
}

/// Reads a driver's device status now (see [`BuiltDriver::status_source`]).
pub type StatusSource = Box<dyn Fn() -> crate::driver_status::DriverStatus + Send>;

impl BuiltDriver {
    /// Its layers.
    pub fn layers(&self) -> Vec<LayerSpec> {
        match self {
            BuiltDriver::Virtual(driver) => driver.layers(),
            BuiltDriver::Can(driver) => driver.layers(),
            BuiltDriver::Ethercat(driver) => driver.layers(),
            #[cfg(feature = "dds")]
            BuiltDriver::Ros2(driver) => driver.layers(),
            BuiltDriver::Replay(replay) => replay
                .header
                .channels
                .values()
                .filter(|c| c.kind == skinware::ChannelKind::Layer)
                .filter_map(|c| skinware::LayerTopology::decode(&c.description, &c.channel).ok())
                .map(|topology| LayerSpec { topology, rt: replay.options.rt.clone() })
                .collect(),
        }
    }

    /// Its own calibration: the virtual skin's body; for a CAN, EtherCAT or ROS 2
    /// skin without a calibration file, a flat layout (modules in rows of 16,
    /// taxels on a 4 mm grid), the driver's `index`-th 0.5 m apart, so that
    /// the viewer shows every taxel.
    pub fn calibration(&self, index: usize) -> Calibration {
        match self {
            BuiltDriver::Virtual(driver) => driver.calibration(),
            BuiltDriver::Replay(replay) => replay_calibration(replay),
            // CAN, EtherCAT and ROS 2: a flat layout.
            _ => {
                let mut calibration = Calibration::new();
                for spec in self.layers() {
                    let topology = spec.topology;
                    for (m, module) in topology.modules.iter().enumerate() {
                        let (column, row) = ((m % 16) as f64, (m / 16) as f64);
                        for (k, sensor) in module.sensors.clone().enumerate() {
                            let x = column * 0.02 + (k % 4) as f64 * 0.004;
                            let y = index as f64 * 0.5 + row * 0.016 + (k / 4) as f64 * 0.004;
                            let entry = SensorCalibration {
                                position: [x, y, 0.0],
                                normal: [0.0, 0.0, 1.0],
                                radius: 0.0015,
                                link: topology.name.clone(),
                            };
                            let _ = calibration.insert(&topology.name, topology.sensors[sensor].uid, entry);
                        }
                    }
                }
                calibration
            }
        }
    }

    /// Its kind.
    pub fn kind(&self) -> DriverKind {
        match self {
            BuiltDriver::Virtual(_) => DriverKind::Virtual,
            BuiltDriver::Can(_) => DriverKind::Can,
            BuiltDriver::Replay(_) => DriverKind::Replay,
            BuiltDriver::Ethercat(_) => DriverKind::Ethercat,
            #[cfg(feature = "dds")]
            BuiltDriver::Ros2(_) => DriverKind::Ros2,
        }
    }

    /// What the driver process publishes of itself for the other commands,
    /// as a function that reads it now: its kind and layers (what `skin
    /// pull` checks), and an EtherCAT bus's SubDevices (what `skin ls`
    /// shows).
    pub fn status_source(&self, skin: &str, driver: &str) -> StatusSource {
        let layers: Vec<String> = self.layers().into_iter().map(|spec| spec.topology.name).collect();
        let (skin, driver, kind) = (skin.to_owned(), driver.to_owned(), self.kind());
        let status = move || crate::driver_status::DriverStatus {
            skin: skin.clone(),
            driver: driver.clone(),
            kind: kind.as_str().into(),
            layers: layers.clone(),
            pid: std::process::id(),
            updated_ns: crate::driver_status::now_ns(),
            bus_fault: None,
            devices: Vec::new(),
        };
        let BuiltDriver::Ethercat(ethercat) = self else {
            return Box::new(status);
        };
        let handle = ethercat.status_handle();
        let layers: Vec<String> = ethercat.layers().into_iter().map(|spec| spec.topology.name).collect();
        Box::new(move || crate::driver_status::DriverStatus {
            bus_fault: handle.bus_fault(),
            devices: handle
                .segments()
                .into_iter()
                .zip(&layers)
                .enumerate()
                .map(|(position, (segment, layer))| crate::driver_status::DeviceStatus {
                    faults: segment.faults,
                    sample_age_ms: (segment.newest_sample_ns != 0)
                        .then(|| crate::driver_status::now_ns().saturating_sub(segment.newest_sample_ns) as f64 * 1e-6),
                    position,
                    layer: layer.clone(),
                    name: segment.name,
                    vendor_id: segment.identity.map(|i| i[0]),
                    product_code: segment.identity.map(|i| i[1]),
                    revision: segment.identity.map(|i| i[2]),
                    serial: segment.identity.map(|i| i[3]),
                    state: segment.state,
                    fault: segment.fault,
                    cycles: segment.cycles,
                    counter: segment.counter,
                })
                .collect(),
            ..status()
        })
    }

    /// The driver, to run under a driver handler; a replay runs on its own
    /// (it publishes at recorded times, not on a period) and gives `None`.
    pub fn into_driver(self) -> Option<Box<dyn Driver>> {
        match self {
            BuiltDriver::Virtual(driver) => Some(Box::new(driver)),
            BuiltDriver::Can(driver) => Some(Box::new(driver)),
            BuiltDriver::Ethercat(driver) => Some(Box::new(driver)),
            #[cfg(feature = "dds")]
            BuiltDriver::Ros2(driver) => Some(driver),
            BuiltDriver::Replay(_) => None,
        }
    }
}

/// The recorded skin's calibration, from the geometry in the recording
/// (without one, none: the config must give a `calibration` file).
fn replay_calibration(replay: &ReplayDriver) -> Calibration {
    let mut calibration = Calibration::new();
    let Some(geometry) =
        replay.header.geometry.as_deref().and_then(|bytes| skinware_geometry::SkinGeometry::decode(bytes).ok())
    else {
        return calibration;
    };
    for (l, layer) in geometry.layers.iter().enumerate() {
        for (k, sensor) in layer.sensors.iter().enumerate() {
            let g = geometry.layer_starts[l] + k;
            let entry = SensorCalibration {
                position: geometry.positions[g].map(f64::from),
                normal: geometry.normals[g].map(f64::from),
                radius: f64::from(geometry.radii[g]),
                link: geometry.links.get(geometry.link_of[g] as usize).cloned().unwrap_or_default(),
            };
            let _ = calibration.insert(&layer.name, sensor.uid, entry);
        }
    }
    calibration
}

/// The file whose existence pulls the cable of `layer` (see `skin pull`).
pub fn pull_file(skin: &str, layer: &str) -> PathBuf {
    pull_file_in(&skinware::shm::segment_dir(), skin, layer)
}

/// The file whose existence pulls the cable of `layer` of a skin whose
/// channels are in the segment directory `dir`.
pub fn pull_file_in(dir: &std::path::Path, skin: &str, layer: &str) -> PathBuf {
    dir.join(format!("skinware-ctl.{skin}.{layer}.pulled"))
}

impl DriverConfig {
    /// Checks what building the driver does not: its restart policy and slots.
    pub(super) fn check(&self) -> Result<()> {
        self.restart.check()?;
        if let Some(slots) = self.slots
            && !(skinware::MIN_SLOTS..=skinware::MAX_SLOTS).contains(&slots)
        {
            bail!("slots = {slots} must be from {} to {}", skinware::MIN_SLOTS, skinware::MAX_SLOTS);
        }
        Ok(())
    }

    /// Refuses a key of another kind of driver, naming whose it is.
    fn refuse_other_kinds_keys(&self) -> Result<()> {
        if self.kind != DriverKind::Replay {
            let replay_keys = [
                ("file", self.file.is_some()),
                ("speed", self.speed.is_some()),
                ("loop", self.loop_.is_some()),
                ("from_s", self.from_s.is_some()),
                ("to_s", self.to_s.is_some()),
                ("services", self.services.is_some()),
            ];
            if let Some((key, _)) = replay_keys.iter().find(|(_, given)| *given) {
                bail!("`{key}` is a setting of kind = \"replay\", not of this driver");
            }
        }
        if self.kind != DriverKind::Ethercat {
            if !self.segments.is_empty() {
                bail!("`[[driver.segment]]` is a setting of kind = \"ethercat\", not of this driver");
            }
            if self.frame_timeout_ms.is_some() {
                bail!("`frame_timeout_ms` is a setting of kind = \"ethercat\", not of this driver");
            }
        }
        if self.kind != DriverKind::Ros2 {
            let ros2_keys = [
                ("topic", self.topic.is_some()),
                ("message", self.message.is_some()),
                ("field", self.field.is_some()),
                ("domain", self.domain.is_some()),
                ("timeout_ms", self.timeout_ms.is_some()),
            ];
            if let Some((key, _)) = ros2_keys.iter().find(|(_, given)| *given) {
                bail!("`{key}` is a setting of kind = \"ros2\", not of this driver");
            }
        }
        Ok(())
    }

    /// Builds the driver this table describes.
    pub fn build(&self, skin: &str) -> Result<BuiltDriver> {
        skinware::shm::validate_name("driver", &self.name)?;
        self.refuse_other_kinds_keys()?;
        match self.kind {
            DriverKind::Ros2 => self.build_ros2(),
            DriverKind::Can => self.build_can().map(BuiltDriver::Can),
            DriverKind::Ethercat => self.build_ethercat().map(BuiltDriver::Ethercat),
            DriverKind::Replay => self.build_replay().map(|r| BuiltDriver::Replay(Box::new(r))),
            DriverKind::Virtual => {
                let can_keys = [
                    ("interface", self.interface.is_some()),
                    ("protocol", self.protocol.is_some()),
                    ("board", !self.boards.is_empty()),
                    ("base_ids", !self.base_ids.is_empty()),
                ];
                if let Some((key, _)) = can_keys.iter().find(|(_, given)| *given) {
                    bail!("`{key}` is a setting of kind = \"can\" (or \"ethercat\"), not of the virtual skin");
                }
                let defaults = VirtualSkinConfig::default();
                let layers = self.layers.unwrap_or(defaults.layers);
                let mut config = VirtualSkinConfig {
                    name: self.name.clone(),
                    sensors: self.sensors.unwrap_or(defaults.sensors),
                    layers,
                    sensors_per_module: self.sensors_per_module.unwrap_or(defaults.sensors_per_module),
                    modules_per_patch: self
                        .modules_per_patch
                        .map(|[a, b]| (a, b))
                        .unwrap_or(defaults.modules_per_patch),
                    rate: self.rate_hz.clone().unwrap_or(defaults.rate),
                    seed: self.seed.unwrap_or(defaults.seed),
                    cable_pulls: self.cable_pulls.clone(),
                    pull_files: None,
                    rt: self.rt.options(),
                    explicit_layers: None,
                    contacts: self.contacts.clone(),
                    random_contacts: self.random_contacts.unwrap_or(true),
                    dead_taxels: self.dead_taxels.clone(),
                    stuck_taxels: self.stuck_taxels.clone(),
                    verify_pattern: self.verify_pattern,
                };
                if !self.explicit_layers.is_empty() {
                    if self.sensors.is_some() || self.layers.is_some() {
                        bail!("give either `sensors`/`layers` (a generated skin) or [[driver.layer]] tables, not both");
                    }
                    let default_rate = match &config.rate {
                        Rate::Fixed(hz) => *hz,
                        Rate::Random { random: [lo, _] } => *lo,
                    };
                    let mut layers = Vec::new();
                    let mut budget = skinware_drivers::MAX_SENSORS;
                    for layer in &self.explicit_layers {
                        let rt = layer.rt.as_ref().unwrap_or(&self.rt).options();
                        layers.push(skinware::LayerSpec { topology: layer.topology(default_rate, &mut budget)?, rt });
                    }
                    config.explicit_layers = Some(layers);
                }
                // Before the layers are named: their number is checked there.
                config.validate()?;
                config.pull_files = Some(config.layer_names().iter().map(|layer| pull_file(skin, layer)).collect());
                VirtualSkin::new(config).map(BuiltDriver::Virtual).map_err(|e| anyhow::anyhow!(e))
            }
        }
    }

    /// Checks a `kind = "replay"` table without reading its file.
    pub(super) fn check_replay(&self) -> Result<()> {
        let others = [
            ("sensors", self.sensors.is_some()),
            ("layers", self.layers.is_some()),
            ("interface", self.interface.is_some()),
            ("protocol", self.protocol.is_some()),
            ("[[driver.layer]]", !self.explicit_layers.is_empty()),
            ("[[driver.segment]]", !self.segments.is_empty()),
        ];
        if let Some((key, _)) = others.iter().find(|(_, given)| *given) {
            bail!("`{key}` is not a setting of kind = \"replay\" (it replays the skin it recorded)");
        }
        if self.file.is_none() {
            bail!("kind = \"replay\" needs `file`, a recording made with `skin record`");
        }
        if let Some(speed) = self.speed
            && !(speed.is_finite() && speed > 0.0)
        {
            bail!("speed = {speed} must be a positive number (1 is the recorded speed)");
        }
        if let (Some(from), Some(to)) = (self.from_s, self.to_s)
            && to <= from
        {
            bail!("to_s = {to} must be after from_s = {from}");
        }
        Ok(())
    }

    /// The replay of a `kind = "replay"` table: reads the recording's header.
    fn build_replay(&self) -> Result<ReplayDriver> {
        self.check_replay()?;
        let file = self.file.clone().unwrap_or_default();
        if !file.is_file() {
            bail!("`file` {} is not a file; give the path of a recording (`skin record OUT.mcap`)", file.display());
        }
        let mut stream = skinware_record::file::RecordStream::open(&file)?;
        let (header, _) = skinware_record::file::read_header(&mut stream)?;
        let options = skinware_record::ReplayOptions {
            speed: self.speed.unwrap_or(1.0),
            at_end: if self.loop_.unwrap_or(true) {
                skinware_record::AtEnd::Loop
            } else {
                skinware_record::AtEnd::Hold
            },
            from_s: self.from_s,
            to_s: self.to_s,
            services: self.services.unwrap_or(false),
            rt: self.rt.options(),
            ..skinware_record::ReplayOptions::default()
        };
        Ok(ReplayDriver { file, header, options })
    }

    /// The driver of a `kind = "ros2"` table: one layer from one topic.
    #[cfg(not(feature = "dds"))]
    fn build_ros2(&self) -> Result<BuiltDriver> {
        bail!(
            "driver {}: kind = \"ros2\" needs a skin built with DDS: `cargo build --release -p skin --features dds`",
            self.name
        )
    }

    /// The driver of a `kind = "ros2"` table: one layer from one topic.
    #[cfg(feature = "dds")]
    fn build_ros2(&self) -> Result<BuiltDriver> {
        use skinware_dds::driver::{Ros2Driver, Ros2Input};
        let foreign_keys = [
            ("sensors", self.sensors.is_some()),
            ("layers", self.layers.is_some()),
            ("[[driver.layer]]", !self.explicit_layers.is_empty()),
            ("interface", self.interface.is_some()),
            ("protocol", self.protocol.is_some()),
        ];
        if let Some((key, _)) = foreign_keys.iter().find(|(_, given)| *given) {
            bail!("`{key}` is not a setting of kind = \"ros2\" (it reads one layer of `taxels` from `topic`)");
        }
        let Some(topic) = &self.topic else {
            bail!("kind = \"ros2\" needs `topic`, the ROS 2 topic to read, e.g. \"/fingertip/pressure\"");
        };
        let Some(message) = &self.message else {
            bail!("kind = \"ros2\" needs `message`: \"PointCloud2\", \"UInt16MultiArray\" or \"Float32MultiArray\"");
        };
        let input = Ros2Input::parse(message, self.field.as_deref())?;
        let Some(taxels) = self.taxels.filter(|t| (1..=1_000_000).contains(t)) else {
            bail!("kind = \"ros2\" needs `taxels`, the layer's sensors (1 to 1,000,000): one value each per message");
        };
        let rate_hz = match &self.rate_hz {
            Some(Rate::Fixed(hz)) if (0.01..=100_000.0).contains(hz) => *hz,
            _ => bail!(
                "kind = \"ros2\" needs `rate_hz`, one number from 0.01 to 100000: the rate the topic is published at"
            ),
        };
        // At least two periods (one period without a new message is
        // ordinary jitter), at most an hour.
        let two_periods_ms = 2e3 / rate_hz;
        let timeout_ms = self.timeout_ms.unwrap_or(500.0_f64.max(two_periods_ms));
        if !(timeout_ms.is_finite() && (two_periods_ms..=3.6e6).contains(&timeout_ms)) {
            bail!(
                "timeout_ms = {timeout_ms}: give the silence, in ms, after which the layer is faulted: \
                 from two periods of rate_hz ({two_periods_ms:.1} ms) to an hour (3600000)"
            );
        }
        let domain = match self.domain {
            Some(domain) => skinware_dds::check_domain(domain)?,
            None => skinware_dds::domain_from_env()?,
        };
        let layer = self.layer_name.clone().unwrap_or_else(|| self.name.clone());
        skinware::shm::validate_name("layer", &layer)?;
        let per_module = self.sensors_per_module.unwrap_or(16).max(1);
        let mut builder = skinware::TopologyBuilder::new(&layer, "ros2", rate_hz);
        let patch = builder.patch(1);
        for (m, first) in (0..taxels).step_by(per_module).enumerate() {
            let uids = (first..(first + per_module).min(taxels)).map(|uid| uid as u32);
            patch.module(m as u32, uids);
        }
        let topology = builder.build()?;
        let timeout = std::time::Duration::from_secs_f64(timeout_ms / 1e3);
        let driver = Ros2Driver::new(topology, self.rt.options(), topic, input, domain, timeout)?;
        Ok(BuiltDriver::Ros2(Box::new(driver)))
    }

    /// The CAN driver of a `kind = "can"` table.
    fn build_can(&self) -> Result<CanDriver> {
        let virtual_keys = [
            ("sensors", self.sensors.is_some()),
            ("layers", self.layers.is_some()),
            ("[[driver.layer]]", !self.explicit_layers.is_empty()),
            ("[[driver.contact]]", !self.contacts.is_empty()),
        ];
        if let Some((key, _)) = virtual_keys.iter().find(|(_, given)| *given) {
            bail!("`{key}` is a setting of the virtual skin, not of kind = \"can\"");
        }
        let Some(interface) = self.interface.clone() else {
            bail!(
                "kind = \"can\" needs `interface`, e.g. \"slcan:///dev/ttyACM0?bitrate=1000000\" or \"socketcan://can0\""
            );
        };
        let Some(protocol) = self.protocol else {
            bail!("kind = \"can\" needs `protocol`: \"icub-mtb\", \"cyskin\" or \"xela\"");
        };
        let period_ms = self.period_ms.unwrap_or(20);
        let rate_hz = match &self.rate_hz {
            None => 1000.0 / f64::from(period_ms.max(1)),
            Some(Rate::Fixed(hz)) => *hz,
            Some(Rate::Random { .. }) => bail!("a CAN layer's `rate_hz` is one number"),
        };
        let protocol = match protocol {
            CanProtocol::IcubMtb => {
                if self.boards.is_empty() {
                    bail!("protocol \"icub-mtb\" needs `[[driver.board]]` tables, each with `address` and `triangles`");
                }
                let boards = self
                    .boards
                    .iter()
                    .map(|board| Board {
                        address: board.address,
                        triangles: match &board.triangles {
                            Triangles::Count(count) => (0..*count).collect(),
                            Triangles::List(list) => list.clone(),
                        },
                    })
                    .collect();
                let defaults = BoardSettings::default();
                let settings = BoardSettings {
                    period_ms,
                    no_load: self.no_load.unwrap_or(defaults.no_load),
                    shift: self.shift.unwrap_or(defaults.shift),
                    ..defaults
                };
                Protocol::IcubMtb { boards, settings }
            }
            CanProtocol::Cyskin => Protocol::CySkin {
                base_ids: if self.base_ids.is_empty() {
                    vec![skinware_drivers::can::cyskin::DEFAULT_BASE_ID]
                } else {
                    self.base_ids.clone()
                },
            },
            CanProtocol::Xela => Protocol::Xela { board: self.address.unwrap_or(1), taxels: self.taxels.unwrap_or(16) },
        };
        let layer = self.layer_name.clone().unwrap_or_else(|| self.name.clone());
        skinware::shm::validate_name("layer", &layer)?;
        CanDriver::new(CanDriverConfig {
            name: self.name.clone(),
            layer,
            interface,
            protocol,
            rate_hz,
            rt: self.rt.options(),
        })
        .map_err(anyhow::Error::msg)
    }

    /// The EtherCAT driver of a `kind = "ethercat"` table.
    fn build_ethercat(&self) -> Result<EthercatDriver> {
        let foreign_keys = [
            ("sensors", self.sensors.is_some()),
            ("layers", self.layers.is_some()),
            ("[[driver.layer]]", !self.explicit_layers.is_empty()),
            ("[[driver.contact]]", !self.contacts.is_empty()),
            ("protocol", self.protocol.is_some()),
            ("[[driver.board]]", !self.boards.is_empty()),
            ("base_ids", !self.base_ids.is_empty()),
            ("layer_name", self.layer_name.is_some()),
        ];
        if let Some((key, _)) = foreign_keys.iter().find(|(_, given)| *given) {
            bail!("`{key}` is not a setting of kind = \"ethercat\" (its layers come from `[[driver.segment]]`)");
        }
        let Some(interface) = self.interface.clone() else {
            bail!("kind = \"ethercat\" needs `interface`, the network interface of the EtherCAT port, e.g. \"eth0\"");
        };
        // Linux interface names: 1 to 15 bytes, no slash or white space.
        if interface.is_empty() || interface.len() > 15 || interface.contains(['/', ' ', '\t']) {
            bail!("interface = {interface:?} is not a network interface name (1 to 15 characters, no '/' or spaces)");
        }
        if self.segments.is_empty() {
            bail!(
                "kind = \"ethercat\" needs `[[driver.segment]]` tables, one per SubDevice in ring order, \
                 each with `vendor_id`, `product_code` and `taxels`"
            );
        }
        let rate_hz = match &self.rate_hz {
            None => 1000.0,
            Some(Rate::Fixed(hz)) => *hz,
            Some(Rate::Random { .. }) => bail!("an EtherCAT driver's `rate_hz` is one number"),
        };
        let frame_timeout = match self.frame_timeout_ms {
            None => None,
            Some(ms) if ms.is_finite() && ms > 0.0 && ms <= 10_000.0 => {
                Some(std::time::Duration::from_secs_f64(ms / 1e3))
            }
            Some(ms) => bail!("frame_timeout_ms = {ms} must be above 0 and at most 10000"),
        };
        let mut segments = Vec::new();
        for (position, table) in self.segments.iter().enumerate() {
            let layer = table.layer.clone().unwrap_or_else(|| format!("{}-{position}", self.name));
            skinware::shm::validate_name("layer", &layer).with_context(|| format!("segment {position}"))?;
            // Before anything is built from it: a count from the file sizes the modules.
            let max = skinware_drivers::ethercat::MAX_TAXELS;
            if table.taxels == 0 || table.taxels > max {
                bail!("segment {position}: taxels = {}; a segment has 1 to {max}", table.taxels);
            }
            let modules = match (&table.modules, table.sensors_per_module) {
                (Some(_), Some(_)) => {
                    bail!("segment {position}: give `modules` or `sensors_per_module`, not both")
                }
                (Some(modules), None) => modules.clone(),
                (None, Some(0)) => bail!("segment {position}: sensors_per_module = 0; give 1 or more"),
                (None, Some(size)) => {
                    let mut modules = vec![size; table.taxels / size];
                    if !table.taxels.is_multiple_of(size) {
                        modules.push(table.taxels % size);
                    }
                    modules
                }
                (None, None) => Vec::new(),
            };
            segments.push(SegmentConfig {
                layer,
                vendor_id: table.vendor_id,
                product_code: table.product_code,
                taxels: table.taxels,
                modules,
                patch: table.patch.unwrap_or(position as u32 + 1),
                baseline: table.baseline,
            });
        }
        let config =
            EthercatDriverConfig { name: self.name.clone(), segments, rate_hz, frame_timeout, rt: self.rt.options() };
        EthercatDriver::new(config, FrameLink::Interface(interface)).map_err(anyhow::Error::msg)
    }
}
