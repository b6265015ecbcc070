//! Drivers written in C: a layer's topology, built, and its writer.

use std::ffi::c_char;

use super::*;
use crate::handles::{self, WriterChoices};

/// Who may open a writer's channel.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum skinware_access {
    /// The writer's user only (the default).
    SKINWARE_ACCESS_OWNER = 0,
    /// The writer's group too.
    SKINWARE_ACCESS_GROUP = 1,
    /// Every local user.
    SKINWARE_ACCESS_EVERYONE = 2,
}

/// How a writer creates its channel. A NULL options pointer means all zero.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct skinware_writer_options {
    /// Frame buffers (K); 0 for the default, 3.
    pub slots: usize,
    /// A `skinware_access` value (0: the owner only).
    pub access: i32,
}

/// A new, empty topology builder for layer `name` of sensors of type
/// `sensor_type` ("pressure"), acquired at `rate_hz` (0: sporadic, answering
/// requests). Add modules with `skinware_topology_builder_add_module`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_topology_builder_new(
    name: *const c_char,
    sensor_type: *const c_char,
    rate_hz: f64,
    builder: *mut *mut skinware_topology_builder,
) -> skinware_status {
    let function = "skinware_topology_builder_new";
    entry(|| {
        let out = Out::new(builder, function, "builder")?;
        let name = text(name, function, "name")?;
        let sensor_type = text(sensor_type, function, "sensor_type")?;
        let rate_hz = handles::rate(rate_hz, function)?;
        let inner = skinware::TopologyBuilder::new(name, sensor_type, rate_hz);
        out.put(register(
            &BUILDERS,
            BuilderHandle { inner: std::sync::Mutex::new((inner, None)) },
            "topology builder",
        )?);
        Ok(())
    })
}

/// Adds module `module_id` of patch `patch_id` with the `count` sensors whose
/// hardware uids are `uids[0..count]`, in frame order. Modules of one patch
/// are added one after another; a new `patch_id` starts a new patch.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_topology_builder_add_module(
    builder: *mut skinware_topology_builder,
    patch_id: u32,
    module_id: u32,
    uids: *const u32,
    count: usize,
) -> skinware_status {
    let function = "skinware_topology_builder_add_module";
    entry(|| {
        let builder = live(&BUILDERS, builder, function, "topology builder")?;
        let uids = array(uids, count, function, "uids")?;
        builder.add_module(patch_id, module_id, uids);
        Ok(())
    })
}

/// Checks and builds the topology (unique uids, non-empty modules, ...) into
/// a new `*topology`. The builder stays usable; free both.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_topology_builder_build(
    builder: *const skinware_topology_builder,
    topology: *mut *mut skinware_topology,
) -> skinware_status {
    let function = "skinware_topology_builder_build";
    entry(|| {
        let out = Out::new(topology, function, "topology")?;
        let built = live(&BUILDERS, builder, function, "topology builder")?.build()?;
        out.put(register(&TOPOLOGIES, built, "topology")?);
        Ok(())
    })
}

/// Frees `builder` (NULL is ignored).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_topology_builder_free(builder: *mut skinware_topology_builder) -> skinware_status {
    entry(|| release(&BUILDERS, builder, "skinware_topology_builder_free", "topology builder").map(drop))
}

/// A topology of `patches` patches of `modules_per_patch` modules of
/// `sensors_per_module` sensors, uids 0, 1, 2, ... in order: for tests and
/// simple drivers.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_topology_uniform(
    name: *const c_char,
    sensor_type: *const c_char,
    rate_hz: f64,
    patches: u32,
    modules_per_patch: u32,
    sensors_per_module: u32,
    topology: *mut *mut skinware_topology,
) -> skinware_status {
    let function = "skinware_topology_uniform";
    entry(|| {
        let out = Out::new(topology, function, "topology")?;
        let name = text(name, function, "name")?;
        let sensor_type = text(sensor_type, function, "sensor_type")?;
        let rate_hz = handles::rate(rate_hz, function)?;
        handles::uniform_sensors(patches, modules_per_patch, sensors_per_module)?;
        let mut builder = skinware::TopologyBuilder::new(name, sensor_type, rate_hz);
        let mut uid = 0;
        for patch in 0..patches {
            builder.patch(patch);
            for module in 0..modules_per_patch {
                builder.module(patch * modules_per_patch + module, uid..uid + sensors_per_module);
                uid += sensors_per_module;
            }
        }
        let built = builder.build().map_err(|e| Failure::invalid(function, e))?;
        out.put(register(&TOPOLOGIES, TopologyHandle::new(built), "topology")?);
        Ok(())
    })
}

/// Creates layer `layer` of skin `skin` with `topology` (its rate decides
/// periodic or sporadic) and becomes its writer. `options` may be NULL.
/// `SKINWARE_E_BUSY` if a live writer has the name; a dead writer's channel
/// is taken over, and its readers follow. Close with `skinware_writer_close`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_writer_create(
    skin: *const c_char,
    layer: *const c_char,
    topology: *const skinware_topology,
    options: *const skinware_writer_options,
    writer: *mut *mut skinware_writer,
) -> skinware_status {
    let function = "skinware_writer_create";
    entry(|| {
        let out = Out::new(writer, function, "writer")?;
        let skin = text(skin, function, "skin")?;
        let layer = text(layer, function, "layer")?;
        let topology = live(&TOPOLOGIES, topology, function, "topology")?;
        let options = input(options, function, "options")?.copied().unwrap_or_default();
        let choices = WriterChoices { slots: handles::slots(options.slots)?, access: handles::access(options.access)? };
        let created = WriterHandle::create(skin, layer, &topology.inner, choices)?;
        out.put(register(&WRITERS, created, "writer")?);
        Ok(())
    })
}

/// Publishes one frame: `count` responses (exactly the layer's sensors, in
/// topology order) with status bits `status` (0: good; `SKINWARE_FRAME_FAULT`
/// ...), acquired at `acquired_ns` (CLOCK_MONOTONIC; 0: now). Wait-free:
/// never waits for readers. The new frame's sequence number goes to `*seq`
/// (NULL if not wanted).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_writer_publish(
    writer: *mut skinware_writer,
    responses: *const u16,
    count: usize,
    status: u64,
    acquired_ns: u64,
    seq: *mut u64,
) -> skinware_status {
    let function = "skinware_writer_publish";
    entry(|| {
        let seq = Out::optional(seq, function, "seq")?;
        let writer = live(&WRITERS, writer, function, "writer")?;
        // The count is checked before C's array is looked at.
        let sensors = writer.topology.sensors.len();
        if count != sensors {
            return Err(Failure::invalid(
                function,
                format_args!("layer {} has {sensors} sensors, {count} responses given", writer.label),
            ));
        }
        let responses = array(responses, count, function, "responses")?;
        let published = writer.publish(responses, status, acquired_ns)?;
        if let Some(seq) = seq {
            seq.put(published);
        }
        Ok(())
    })
}

/// Sets the state readers see: `SKINWARE_STATE_RUNNING`, `_PAUSED` or
/// `_FAULTED` (a driver whose device stopped answering).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_writer_set_state(writer: *mut skinware_writer, state: i32) -> skinware_status {
    let function = "skinware_writer_set_state";
    entry(|| {
        let writer = live(&WRITERS, writer, function, "writer")?;
        let state = handles::settable_state(state)?;
        skinware::lock(&writer.core).set_state(state);
        Ok(())
    })
}

/// The state the writer set, in `*state`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_writer_get_state(
    writer: *const skinware_writer,
    state: *mut skinware_writer_state,
) -> skinware_status {
    let function = "skinware_writer_get_state";
    entry(|| {
        let out = Out::new(state, function, "state")?;
        out.put(skinware::lock(&live(&WRITERS, writer, function, "writer")?.core).state().into());
        Ok(())
    })
}

/// A sporadic writer's loop: waits up to `timeout_ns` for a reader's
/// request; `*requested` is true if one came (publish a frame then), false
/// on timeout. `SKINWARE_E_STOPPED` after `skinware_writer_stop`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_writer_wait_request(
    writer: *mut skinware_writer,
    timeout_ns: u64,
    requested: *mut bool,
) -> skinware_status {
    let function = "skinware_writer_wait_request";
    entry(|| {
        let out = Out::new(requested, function, "requested")?;
        let writer = live(&WRITERS, writer, function, "writer")?;
        out.put(writer.wait_request(handles::timeout(timeout_ns))?);
        Ok(())
    })
}

/// A periodic writer's schedule: a new ticker at the layer's rate, in
/// `*ticker` (`SKINWARE_E_INVALID_ARGUMENT` for a sporadic layer). Loop on
/// `skinware_ticker_wait`, then acquire and publish. Free it with
/// `skinware_ticker_free`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_writer_ticker(
    writer: *const skinware_writer,
    ticker: *mut *mut skinware_ticker,
) -> skinware_status {
    let function = "skinware_writer_ticker";
    entry(|| {
        let out = Out::new(ticker, function, "ticker")?;
        let writer = live(&WRITERS, writer, function, "writer")?;
        let Some(period) = writer.period else {
            return Err(Failure::invalid(
                function,
                format_args!(
                    "{} is sporadic (rate 0): answer requests with skinware_writer_wait_request",
                    writer.label
                ),
            ));
        };
        let period_ns = period.as_nanos().min(u128::from(u64::MAX)) as u64;
        out.put(register(&TICKERS, TickerHandle::new(period_ns, function)?, "ticker")?);
        Ok(())
    })
}

/// The writer's statistics in `*stats`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_writer_get_stats(
    writer: *const skinware_writer,
    stats: *mut skinware_writer_stats,
) -> skinware_status {
    let function = "skinware_writer_get_stats";
    entry(|| {
        let out = Out::new(stats, function, "stats")?;
        out.put(skinware::lock(&live(&WRITERS, writer, function, "writer")?.core).stats().into());
        Ok(())
    })
}

/// Stops `skinware_writer_wait_request` from any thread: a blocked wait and
/// every later one return `SKINWARE_E_STOPPED`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_writer_stop(writer: *const skinware_writer) -> skinware_status {
    entry(|| {
        live(&WRITERS, writer, "skinware_writer_stop", "writer")?.stop.stop();
        Ok(())
    })
}

/// Closes the channel and frees `writer` (NULL is ignored): readers see the
/// writer gone, keep its last frames, and follow a successor.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_writer_close(writer: *mut skinware_writer) -> skinware_status {
    entry(|| {
        if let Some(writer) = release(&WRITERS, writer, "skinware_writer_close", "writer")? {
            writer.stop.stop();
        }
        Ok(())
    })
}
