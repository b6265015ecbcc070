//! Benchmarks of skinware, run as `skin bench ...`: commands that print tables
//! and write JSON (and a plot), never timed unit tests.
//!
//! * [`paper`]: the paper's performance test (Section IV.B, Fig. 6): the
//!   30,848-sensor virtual skin over 1..5 layers, read by 1..15 application
//!   processes; writers' and readers' execution times.
//! * [`table1`]: the paper's Table I: a 180-sensor "CAN" layer and a
//!   708-sensor "EtherCAT" layer with aperiodic readers.
//! * [`peers`]: the whole-skin frame delivered to 1, 4 and 15 reader
//!   processes through skinware and through a lock-based shared-memory
//!   baseline, beside `memcpy` and `cyclictest`.
//! * [`contact`]: the contact service's cost per frame on the paper's skin
//!   with scripted contacts: the detector alone, and the running service.
//!
//! * [`wake`]: a 1 kHz writer of the whole skin's frame with 0 or 15 readers
//!   asleep on the futex, woken by the writer or by its ringer.
//!
//! * [`follow`]: how soon readers in every mode get a restarted writer's
//!   first frame, with the successor watcher and with the old 100 ms re-check.
//!
//! * [`ethercat`]: the EtherCAT driver on a veth pair against the ESC
//!   model: cycle rate and jitter at 1 kHz, latency from the SubDevice to a
//!   reader, fault detection and recovery times.
//!
//! * [`soak`]: an hour (or any time) of faults on a skin under `skin run`,
//!   with readers that verify every frame: torn, backwards and silently
//!   lost frames, stuck readers, leaks, and how long every layer takes to
//!   run again after each kind of fault.
//!
//! * [`kilohertz`]: the paper's skin at 1 kHz alone and with everything
//!   that reads it (applications, services, the viewer and its browsers, the
//!   recorder); then the viewer with 1 and 10 browsers beside a floor server.
//!
//! * [`bridge`]: the paper's skin across a veth link between two network
//!   namespaces, through `skin bridge` (feature `zenoh`).
//!
//! * [`ros2`]: the skin's ROS 2 topics to stock rclpy subscribers, over
//!   DDS (feature `dds`) and rmw_zenoh (feature `zenoh`), beside rclpy to
//!   rclpy.
//!
//! * [`chromium`]: the viewer's page in headless Chromium through
//!   chromedriver, for `kilohertz --chromium` and the `skin` crate's
//!   browser tests.
//!
//! Every bench takes a [`RunOptions`] (quick or full, where its files go,
//! seconds per configuration, the `skin` executable), alone or inside its
//! own options. Helper processes (application processes, readers, the floor
//! server, the soak's helpers) are the `skin` executable run again with a
//! hidden role ([`roles`]).
//!
//! Cargo features: `iceoryx2` adds iceoryx2 to [`peers`]; `zenoh` builds
//! [`bridge`] (without it, the bridge bench says how to get it) and the
//! rmw_zenoh rows of [`ros2`]; `dds` its DDS rows.

// `unsafe` is denied everywhere but in the lock-based peer (pthread objects
// in shared memory), which says so itself.
#![deny(unsafe_code)]

pub mod app;
pub mod bridge;
pub mod c;
pub mod can;
pub mod chromium;
pub mod contact;
pub mod ethercat;
pub mod follow;
#[cfg(feature = "iceoryx2")]
mod iceoryx2_peer;
pub mod kilohertz;
pub mod measure;
pub mod netns;
pub mod paper;
mod paper_record;
pub mod peers;
mod plot;
pub mod procs;
pub mod python;
pub mod record;
pub mod recorder;
pub mod roles;
pub mod ros2;
pub mod run_options;
mod rwlock_peer;
pub mod scale;
mod scale_record;
pub mod skin_config;
pub mod soak;
pub mod table1;
pub mod wake;

pub use run_options::RunOptions;
