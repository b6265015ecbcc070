//! Skinware services: users of tactile data that publish processed data to
//! other users, through the same exchange as the layers.
//!
//! * [`framework`]: what every service is made of: typed records
//!   ([`ServicePayload`]), a [`ServiceWriter`] that publishes them
//!   periodically or on request, and a [`ServiceReader`] that refuses records
//!   of another type or version.
//!
//! * [`contact`]: per-taxel baseline with drift compensation, a touch
//!   threshold from the measured noise, contacts per region (centroid in 3-D
//!   and on the 2-D map, mean normal, area, total and peak pressure), dead and
//!   stuck taxels. It publishes `NAME` ([`RegionContacts`] per region) and
//!   `NAME-taxels` ([`TaxelState`] per taxel).
//! * [`motion`]: the paper's motion detection, built on the contact service:
//!   per region, whether the main contact slides, its velocity on the map and
//!   in 3-D, where it started and where it is.
//!
//! Both run as standalone processes (`skin run` starts the `[[service]]`
//! tables of its config) or inside any application, with
//! [`run_contact_service`] and [`run_motion_service`].
//!
//! ```no_run
//! use skinware_services::framework::ServiceReader;
//! use skinware_services::{RegionContacts, MotionRecord, motion_flags};
//!
//! let mut motion = ServiceReader::<MotionRecord>::open("default", "motion")?;
//! let labels = motion.labels().to_vec();
//! let frame = motion.wait_newer(std::time::Duration::from_secs(1))?;
//! for (region, record) in labels.iter().zip(frame.records) {
//!     if record.flags & motion_flags::SLIDING != 0 {
//!         println!("{region}: sliding at {:.3} m/s", record.speed_3d);
//!     }
//! }
//! # Ok::<(), skinware::Error>(())
//! ```

#![forbid(unsafe_code)]

pub mod contact;
pub mod framework;
pub mod inputs;
pub mod motion;

use std::time::Duration;

use skinware::{FrameStatus, ReaderOptions, Stop, WriterOptions, WriterState};
use skinware_geometry::SkinGeometry;

pub use contact::{Contact, ContactDetector, ContactParams, MAX_CONTACTS, RegionContacts, TaxelState, contact_flags};
pub use framework::{
    ServiceFrame, ServiceInfo, ServiceMode, ServicePayload, ServiceReader, ServiceSpec, ServiceWriter, StepOutcome,
};
pub use inputs::SkinInputs;
pub use motion::{MotionParams, MotionRecord, MotionTracker, motion_flags};

/// What can stop a service.
#[derive(Debug, thiserror::Error)]
pub enum ServiceError {
    /// The exchange refused (a channel, a schema, a layout).
    #[error(transparent)]
    Exchange(#[from] skinware::Error),
    /// The skin's geometry is missing or unusable.
    #[error(transparent)]
    Geometry(#[from] skinware_geometry::GeometryError),
}

/// The contact service's settings.
#[derive(Clone, Debug)]
pub struct ContactServiceConfig {
    /// Channel name; the per-taxel states go to `NAME-taxels`.
    pub name: String,
    /// Periodic or sporadic.
    pub mode: ServiceMode,
    /// Detection parameters.
    pub params: ContactParams,
}

/// The motion service's settings.
#[derive(Clone, Debug)]
pub struct MotionServiceConfig {
    /// Channel name.
    pub name: String,
    /// Periodic or sporadic.
    pub mode: ServiceMode,
    /// The contact service it reads.
    pub input: String,
    /// Tracking parameters.
    pub params: MotionParams,
}

/// A periodic writer's frame older than this many of its periods is stale:
/// its writer has stopped publishing without saying so.
pub const STALE_PERIODS: u32 = 5;

/// Whether a frame published at `published_ns` by a writer of period
/// `period` (`None`: sporadic, whose frames are as fresh as the last
/// request) is stale now.
pub fn is_stale(published_ns: u64, period: Option<Duration>) -> bool {
    period.is_some_and(|period| {
        let age = skinware::os::monotonic_ns().saturating_sub(published_ns);
        u128::from(age) > u128::from(STALE_PERIODS) * period.as_nanos()
    })
}

/// The per-taxel channel of contact service `name`.
pub fn taxel_channel(name: &str) -> String {
    format!("{name}-taxels")
}

/// Runs the contact service on `skin` until `stop`.
pub fn run_contact_service(
    skin: &str,
    config: &ContactServiceConfig,
    geometry: &SkinGeometry,
    options: &WriterOptions,
    stop: &Stop,
) -> Result<(), ServiceError> {
    let mut inputs = SkinInputs::new(skin, geometry);
    let mut detector = ContactDetector::new(geometry, config.params.clone());
    let mut spec = ServiceSpec::new(&config.name, detector.region_names().to_vec(), config.mode);
    spec.inputs = inputs.names().to_vec();
    let mut service = ServiceWriter::<RegionContacts>::create(skin, &spec, options)?;
    let mut taxel_spec = ServiceSpec::unlabelled(&taxel_channel(&config.name), geometry.sensor_count(), config.mode);
    taxel_spec.inputs = inputs.names().to_vec();
    let mut taxels = ServiceWriter::<TaxelState>::create(skin, &taxel_spec, options)?;
    service.writer().set_stop(stop);
    let mut previous: Option<u64> = None;
    service.run(|records| -> Result<StepOutcome, skinware::Error> {
        let all_up = inputs.update();
        let now = skinware::os::monotonic_ns();
        let dt_s = previous.map_or(0.0, |p| (now.saturating_sub(p)) as f32 * 1e-9);
        previous = Some(now);
        let layer_responses = |layer| inputs.layer_responses(layer);
        detector.update_layers(geometry, layer_responses, &inputs.layer_ok, &inputs.layer_fresh, dt_s, records);
        let status = if all_up { FrameStatus::OK } else { FrameStatus::INPUT_FAULTED };
        taxels.publish(detector.taxel_states(), status)?;
        Ok(StepOutcome { status, acquired_ns: (inputs.acquired_ns > 0).then_some(inputs.acquired_ns) })
    })?;
    Ok(())
}

/// Runs the motion service on `skin` until `stop`. It waits for its input
/// (the contact service) to exist.
pub fn run_motion_service(
    skin: &str,
    config: &MotionServiceConfig,
    options: &WriterOptions,
    stop: &Stop,
) -> Result<(), ServiceError> {
    let reader_options = ReaderOptions { allow_gone: true, ..ReaderOptions::default() };
    let mut contacts = loop {
        match ServiceReader::<RegionContacts>::open_with(skin, &config.input, &reader_options) {
            Ok(reader) => break reader,
            Err(skinware::Error::Missing { .. }) if !stop.is_stopped() => std::thread::sleep(Duration::from_millis(50)),
            Err(e) => return Err(e.into()),
        }
    };
    let labels = contacts.labels().to_vec();
    let mut tracker = MotionTracker::new(labels.len(), config.params.clone());
    let mut spec = ServiceSpec::new(&config.name, labels, config.mode);
    spec.inputs = vec![config.input.clone()];
    let mut service = ServiceWriter::<MotionRecord>::create(skin, &spec, options)?;
    service.writer().set_stop(stop);
    let mut last_seq = 0;
    let mut last_acquired = None;
    service.run(|records| -> Result<StepOutcome, skinware::Error> {
        contacts.reader().follow_recreated();
        let running = contacts.writer_state() == WriterState::Running;
        let period = contacts.reader().writer_period();
        let mut status = FrameStatus::OK;
        let newest = if period.is_none() {
            // A sporadic contact service publishes only when asked.
            contacts.request(Duration::from_millis(100))
        } else {
            contacts.latest()
        };
        match newest {
            Ok(frame) => {
                let input_ok = running && !is_stale(frame.published_ns, period);
                if !input_ok || frame.status.contains(FrameStatus::INPUT_FAULTED) {
                    status = FrameStatus::INPUT_FAULTED;
                }
                if frame.seq != last_seq || !input_ok {
                    last_seq = frame.seq;
                    last_acquired = Some(frame.acquired_ns);
                    tracker.update(frame.records, frame.acquired_ns as f64 * 1e-9, input_ok, records);
                }
            }
            Err(
                skinware::Error::NoFrameYet { .. }
                | skinware::Error::Timeout { .. }
                | skinware::Error::WriterGone { .. },
            ) => status = FrameStatus::INPUT_FAULTED,
            Err(e) => return Err(e),
        }
        Ok(StepOutcome { status, acquired_ns: last_acquired })
    })?;
    Ok(())
}
