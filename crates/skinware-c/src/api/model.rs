//! The skin model: topologies (patches, modules, sensors, uid lookup), the
//! geometry's arrays, and the services' record types.

use std::ffi::c_char;
use std::mem::offset_of;

use skinware_services::{Contact, MotionRecord, RegionContacts};

use super::*;
use crate::handles;

/// A topology's summary. The strings belong to the topology.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct skinware_topology_summary {
    /// The layer's name.
    pub name: *const c_char,
    /// Its sensors' type ("pressure").
    pub sensor_type: *const c_char,
    /// Its acquisition rate, Hz; 0 for sporadic.
    pub rate_hz: f64,
    /// Sensors (responses per frame).
    pub sensors: usize,
    /// Modules.
    pub modules: usize,
    /// Patches.
    pub patches: usize,
}

/// One sensor (taxel) of a topology.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct skinware_sensor {
    /// Its hardware uid.
    pub uid: u32,
    /// Its module's id.
    pub module_id: u32,
    /// Its patch's id.
    pub patch_id: u32,
    /// Its module's index (`skinware_topology_module`).
    pub module_index: usize,
    /// Its patch's index (`skinware_topology_patch`).
    pub patch_index: usize,
}

/// One module of a topology: sensors `first_sensor` to `first_sensor + sensors - 1`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct skinware_module {
    /// Its id.
    pub id: u32,
    /// Its patch's id.
    pub patch_id: u32,
    /// Its patch's index.
    pub patch_index: usize,
    /// Index of its first sensor.
    pub first_sensor: usize,
    /// How many sensors it has.
    pub sensors: usize,
}

/// One patch of a topology: modules `first_module` to `first_module + modules - 1`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct skinware_patch {
    /// Its id.
    pub id: u32,
    /// Index of its first module.
    pub first_module: usize,
    /// How many modules it has.
    pub modules: usize,
}

/// Summarises `topology` in `*summary`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_topology_describe(
    topology: *const skinware_topology,
    summary: *mut skinware_topology_summary,
) -> skinware_status {
    let function = "skinware_topology_describe";
    entry(|| {
        let out = Out::new(summary, function, "summary")?;
        let t = live(&TOPOLOGIES, topology, function, "topology")?;
        out.put(skinware_topology_summary {
            name: t.name.as_ptr(),
            sensor_type: t.sensor_type.as_ptr(),
            rate_hz: t.inner.rate_hz,
            sensors: t.inner.sensors.len(),
            modules: t.inner.modules.len(),
            patches: t.inner.patches.len(),
        });
        Ok(())
    })
}

/// Sensor `index` (frame order) of `topology` in `*sensor`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_topology_sensor(
    topology: *const skinware_topology,
    index: usize,
    sensor: *mut skinware_sensor,
) -> skinware_status {
    let function = "skinware_topology_sensor";
    entry(|| {
        let out = Out::new(sensor, function, "sensor")?;
        let t = &live(&TOPOLOGIES, topology, function, "topology")?.inner;
        let s = t.sensors.get(index).ok_or_else(|| handles::out_of_range("sensor", index, t.sensors.len(), &t.name))?;
        let module = &t.modules[s.module];
        out.put(skinware_sensor {
            uid: s.uid,
            module_id: module.id,
            patch_id: t.patches[module.patch].id,
            module_index: s.module,
            patch_index: module.patch,
        });
        Ok(())
    })
}

/// Module `index` of `topology` in `*module`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_topology_module(
    topology: *const skinware_topology,
    index: usize,
    module: *mut skinware_module,
) -> skinware_status {
    let function = "skinware_topology_module";
    entry(|| {
        let out = Out::new(module, function, "module")?;
        let t = &live(&TOPOLOGIES, topology, function, "topology")?.inner;
        let m = t.modules.get(index).ok_or_else(|| handles::out_of_range("module", index, t.modules.len(), &t.name))?;
        out.put(skinware_module {
            id: m.id,
            patch_id: t.patches[m.patch].id,
            patch_index: m.patch,
            first_sensor: m.sensors.start,
            sensors: m.sensors.len(),
        });
        Ok(())
    })
}

/// Patch `index` of `topology` in `*patch`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_topology_patch(
    topology: *const skinware_topology,
    index: usize,
    patch: *mut skinware_patch,
) -> skinware_status {
    let function = "skinware_topology_patch";
    entry(|| {
        let out = Out::new(patch, function, "patch")?;
        let t = &live(&TOPOLOGIES, topology, function, "topology")?.inner;
        let p = t.patches.get(index).ok_or_else(|| handles::out_of_range("patch", index, t.patches.len(), &t.name))?;
        out.put(skinware_patch { id: p.id, first_module: p.modules.start, modules: p.modules.len() });
        Ok(())
    })
}

/// The index (frame order) of the sensor with hardware uid `uid`, in
/// `*index`; `SKINWARE_E_NOT_FOUND` if the layer has no such sensor.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_topology_index_of(
    topology: *const skinware_topology,
    uid: u32,
    index: *mut usize,
) -> skinware_status {
    let function = "skinware_topology_index_of";
    entry(|| {
        let out = Out::new(index, function, "index")?;
        let t = &live(&TOPOLOGIES, topology, function, "topology")?.inner;
        let found = t
            .sensor_by_uid(uid)
            .ok_or_else(|| Failure::not_found(format!("layer {} has no sensor with uid {uid}", t.name)))?;
        out.put(found);
        Ok(())
    })
}

/// Copies every sensor's uid, in frame order, into `uids[0..count]`;
/// `count` must be the number of sensors.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_topology_uids(
    topology: *const skinware_topology,
    uids: *mut u32,
    count: usize,
) -> skinware_status {
    let function = "skinware_topology_uids";
    entry(|| {
        let t = &live(&TOPOLOGIES, topology, function, "topology")?.inner;
        if count < t.sensors.len() {
            return Err(Failure::new(
                skinware_status::SKINWARE_E_BUFFER_TOO_SMALL,
                format!("{function}: layer {} has {} sensors, room for {count} uids given", t.name, t.sensors.len()),
            ));
        }
        if count > t.sensors.len() {
            return Err(Failure::invalid(
                function,
                format_args!(
                    "layer {} has {} sensors; give count = {}, not {count}",
                    t.name,
                    t.sensors.len(),
                    t.sensors.len()
                ),
            ));
        }
        let out = array_mut(uids, count, function, "uids")?;
        for (to, sensor) in out.iter_mut().zip(&t.sensors) {
            *to = sensor.uid;
        }
        Ok(())
    })
}

/// Frees `topology` (NULL is ignored).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_topology_free(topology: *mut skinware_topology) -> skinware_status {
    entry(|| release(&TOPOLOGIES, topology, "skinware_topology_free", "topology").map(drop))
}

/// The geometry's summary. The strings belong to the geometry.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct skinware_geometry_summary {
    /// The skin's name.
    pub skin: *const c_char,
    /// Sensors of every layer, in global order (layer after layer).
    pub sensors: usize,
    /// Layers.
    pub layers: usize,
    /// Links (rigid bodies the skin covers).
    pub links: usize,
    /// Regions.
    pub regions: usize,
    /// Sub-regions (the disjoint pieces the regions cut the skin into).
    pub subregions: usize,
    /// Entries of the neighbour list (each edge twice).
    pub neighbour_entries: usize,
}

/// One layer of the geometry: global sensors `first_sensor` to `first_sensor + sensors - 1`.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct skinware_geometry_layer {
    /// The layer's name.
    pub name: *const c_char,
    /// Global index of its first sensor.
    pub first_sensor: usize,
    /// Its sensors.
    pub sensors: usize,
}

/// One region: its sensors (global indices) and its sub-regions. The arrays
/// belong to the geometry.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct skinware_region {
    /// Its name.
    pub name: *const c_char,
    /// Global indices of its sensors, ascending.
    pub sensors: *const u32,
    /// How many.
    pub sensor_count: usize,
    /// Indices of its sub-regions (`skinware_geometry_subregion`).
    pub subregions: *const u32,
    /// How many.
    pub subregion_count: usize,
}

/// Where a global sensor index lives.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct skinware_sensor_ref {
    /// Its layer's index.
    pub layer: usize,
    /// Its index in that layer's frames.
    pub sensor: usize,
    /// Its hardware uid.
    pub uid: u32,
    /// Its module's id.
    pub module_id: u32,
    /// Its patch's id.
    pub patch_id: u32,
}

/// Every array of the geometry, lent until `skinware_geometry_free`: one
/// entry per global sensor unless said otherwise.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct skinware_geometry_arrays {
    /// Positions, metres: x, y, z per sensor (3 floats each).
    pub positions: *const f32,
    /// Outward unit normals: 3 floats per sensor.
    pub normals: *const f32,
    /// Sensing radii, metres.
    pub radii: *const f32,
    /// Positions on the 2-D map, metres: 2 floats per sensor.
    pub map: *const f32,
    /// The map piece each sensor was flattened into.
    pub map_pieces: *const u32,
    /// The link (`skinware_geometry_link`) each sensor is on.
    pub link_of: *const u16,
    /// Neighbours, compressed rows: sensor i's are
    /// `neighbours[neighbour_offsets[i] .. neighbour_offsets[i + 1]]`
    /// (sensors + 1 offsets).
    pub neighbour_offsets: *const u32,
    /// Neighbour lists (global indices), `neighbour_entries` entries.
    pub neighbours: *const u32,
    /// Sensors (entries per-sensor array).
    pub sensors: usize,
    /// Entries of `neighbours`.
    pub neighbour_entries: usize,
}

/// Opens the geometry `skin run` published for skin `skin` (calibration,
/// regions, neighbours, map). `SKINWARE_E_GEOMETRY` says what is missing.
/// Free `*geometry` with `skinware_geometry_free`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_geometry_open(
    skin: *const c_char,
    geometry: *mut *mut skinware_geometry,
) -> skinware_status {
    let function = "skinware_geometry_open";
    entry(|| {
        let out = Out::new(geometry, function, "geometry")?;
        let skin = text(skin, function, "skin")?;
        out.put(register(&GEOMETRIES, GeometryHandle::open(skin)?, "geometry")?);
        Ok(())
    })
}

/// Summarises `geometry` in `*summary`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_geometry_describe(
    geometry: *const skinware_geometry,
    summary: *mut skinware_geometry_summary,
) -> skinware_status {
    let function = "skinware_geometry_describe";
    entry(|| {
        let out = Out::new(summary, function, "summary")?;
        let g = live(&GEOMETRIES, geometry, function, "geometry")?;
        let inner = &g.inner;
        out.put(skinware_geometry_summary {
            skin: g.skin.as_ptr(),
            sensors: inner.sensor_count(),
            layers: inner.layers.len(),
            links: inner.links.len(),
            regions: inner.regions.names.len(),
            subregions: inner.regions.subregion_sensors.len(),
            neighbour_entries: inner.neighbours.list.len(),
        });
        Ok(())
    })
}

/// Lends every per-sensor array of `geometry` in `*arrays`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_geometry_get_arrays(
    geometry: *const skinware_geometry,
    arrays: *mut skinware_geometry_arrays,
) -> skinware_status {
    let function = "skinware_geometry_get_arrays";
    entry(|| {
        let out = Out::new(arrays, function, "arrays")?;
        let g = live(&GEOMETRIES, geometry, function, "geometry")?;
        let inner = &g.inner;
        // The arrays live in the registry's Arc until skinware_geometry_free.
        out.put(skinware_geometry_arrays {
            positions: inner.positions.as_ptr().cast(),
            normals: inner.normals.as_ptr().cast(),
            radii: inner.radii.as_ptr(),
            map: inner.map.positions.as_ptr().cast(),
            map_pieces: inner.map.piece_of.as_ptr(),
            link_of: inner.link_of.as_ptr(),
            neighbour_offsets: inner.neighbours.offsets.as_ptr(),
            neighbours: inner.neighbours.list.as_ptr(),
            sensors: inner.sensor_count(),
            neighbour_entries: inner.neighbours.list.len(),
        });
        Ok(())
    })
}

/// Layer `index` of `geometry` in `*layer`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_geometry_get_layer(
    geometry: *const skinware_geometry,
    index: usize,
    layer: *mut skinware_geometry_layer,
) -> skinware_status {
    let function = "skinware_geometry_get_layer";
    entry(|| {
        let out = Out::new(layer, function, "layer")?;
        let g = live(&GEOMETRIES, geometry, function, "geometry")?;
        let count = g.inner.layers.len();
        let topology =
            g.inner.layers.get(index).ok_or_else(|| handles::out_of_range("layer", index, count, "the skin"))?;
        out.put(skinware_geometry_layer {
            name: g.layer_names[index].as_ptr(),
            first_sensor: g.inner.layer_starts[index],
            sensors: topology.sensors.len(),
        });
        Ok(())
    })
}

/// The name of link `index` in `*name`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_geometry_link(
    geometry: *const skinware_geometry,
    index: usize,
    name: *mut *const c_char,
) -> skinware_status {
    let function = "skinware_geometry_link";
    entry(|| {
        let out = Out::new(name, function, "name")?;
        let g = live(&GEOMETRIES, geometry, function, "geometry")?;
        let found = g
            .link_names
            .get(index)
            .ok_or_else(|| handles::out_of_range("link", index, g.link_names.len(), "the skin"))?;
        out.put(found.as_ptr());
        Ok(())
    })
}

/// Region `index` of `geometry` in `*region`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_geometry_region(
    geometry: *const skinware_geometry,
    index: usize,
    region: *mut skinware_region,
) -> skinware_status {
    let function = "skinware_geometry_region";
    entry(|| {
        let out = Out::new(region, function, "region")?;
        let g = live(&GEOMETRIES, geometry, function, "geometry")?;
        let regions = &g.inner.regions;
        let count = regions.names.len();
        if index >= count {
            return Err(handles::out_of_range("region", index, count, "the skin"));
        }
        out.put(skinware_region {
            name: g.region_names[index].as_ptr(),
            sensors: regions.sensors[index].as_ptr(),
            sensor_count: regions.sensors[index].len(),
            subregions: regions.subregions_of[index].as_ptr(),
            subregion_count: regions.subregions_of[index].len(),
        });
        Ok(())
    })
}

/// The index of region `name` in `*index`; `SKINWARE_E_NOT_FOUND` lists the
/// regions there are.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_geometry_region_index(
    geometry: *const skinware_geometry,
    name: *const c_char,
    index: *mut usize,
) -> skinware_status {
    let function = "skinware_geometry_region_index";
    entry(|| {
        let out = Out::new(index, function, "index")?;
        let name = text(name, function, "name")?;
        let g = live(&GEOMETRIES, geometry, function, "geometry")?;
        let names = &g.inner.regions.names;
        let found = names.iter().position(|n| n == name).ok_or_else(|| {
            handles::unknown("region", name, &format!("skin {}", g.inner.skin), names.iter().cloned())
        })?;
        out.put(found);
        Ok(())
    })
}

/// The sensors (global indices) of sub-region `index`, lent in `*sensors`
/// and `*count`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_geometry_subregion(
    geometry: *const skinware_geometry,
    index: usize,
    sensors: *mut *const u32,
    count: *mut usize,
) -> skinware_status {
    let function = "skinware_geometry_subregion";
    entry(|| {
        let sensors_out = Out::new(sensors, function, "sensors")?;
        let count_out = Out::new(count, function, "count")?;
        let g = live(&GEOMETRIES, geometry, function, "geometry")?;
        let all = &g.inner.regions.subregion_sensors;
        let found = all.get(index).ok_or_else(|| handles::out_of_range("sub-region", index, all.len(), "the skin"))?;
        sensors_out.put(found.as_ptr());
        count_out.put(found.len());
        Ok(())
    })
}

/// Where global sensor `index` lives (layer, sensor, uid, module, patch), in `*found`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_geometry_locate(
    geometry: *const skinware_geometry,
    index: usize,
    found: *mut skinware_sensor_ref,
) -> skinware_status {
    let function = "skinware_geometry_locate";
    entry(|| {
        let out = Out::new(found, function, "found")?;
        let g = live(&GEOMETRIES, geometry, function, "geometry")?;
        let r = g.inner.locate(index).ok_or_else(|| {
            handles::out_of_range("sensor", index, g.inner.sensor_count(), &format!("skin {}", g.inner.skin))
        })?;
        out.put(skinware_sensor_ref {
            layer: r.layer,
            sensor: r.sensor,
            uid: r.uid,
            module_id: r.module_id,
            patch_id: r.patch_id,
        });
        Ok(())
    })
}

/// Frees `geometry` (NULL is ignored); the arrays it lent die with it.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn skinware_geometry_free(geometry: *mut skinware_geometry) -> skinware_status {
    entry(|| release(&GEOMETRIES, geometry, "skinware_geometry_free", "geometry").map(drop))
}

/// Contacts reported per region and frame by the contact service.
pub const SKINWARE_MAX_CONTACTS: usize = 8;
/// `skinware_region_contacts.flags`: a layer under the region is faulted, gone or stale.
pub const SKINWARE_CONTACTS_INPUT_FAULTED: u32 = 1;
/// `skinware_region_contacts.flags`: more contacts than `SKINWARE_MAX_CONTACTS`; the smallest were dropped.
pub const SKINWARE_CONTACTS_MORE: u32 = 2;
/// `skinware_motion_record.flags`: the region's main contact slides.
pub const SKINWARE_MOTION_SLIDING: u32 = 1;
/// `skinware_motion_record.flags`: the region has a contact.
pub const SKINWARE_MOTION_CONTACT: u32 = 2;
/// `skinware_motion_record.flags`: the contact service, or a layer under it, is down here.
pub const SKINWARE_MOTION_INPUT_FAULTED: u32 = 4;

/// One contact: a connected group of touched taxels within one region.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct skinware_contact {
    /// Touched taxels in it.
    pub taxels: u32,
    /// Global index of its most pressed taxel.
    pub peak_sensor: u32,
    /// Pressure-weighted centroid, metres.
    pub centroid: [f32; 3],
    /// Pressure-weighted mean outward normal (unit).
    pub normal: [f32; 3],
    /// Pressure-weighted centroid on the 2-D map, metres.
    pub map: [f32; 2],
    /// Sensing area of its taxels, m².
    pub area_m2: f32,
    /// Sum of responses above baseline.
    pub total: f32,
    /// Largest response above baseline.
    pub peak: f32,
}

/// The contacts of one region in one frame: the contact service's record.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct skinware_region_contacts {
    /// Valid entries of `contacts`, largest total pressure first.
    pub count: u32,
    /// `SKINWARE_CONTACTS_*` bits.
    pub flags: u32,
    /// Dead taxels in the region (never change).
    pub dead: u32,
    /// Stuck taxels in the region (saturated).
    pub stuck: u32,
    /// The contacts; `count` of them are valid.
    pub contacts: [skinware_contact; SKINWARE_MAX_CONTACTS],
}

/// The motion of the main contact of one region: the motion service's record.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default)]
pub struct skinware_motion_record {
    /// `SKINWARE_MOTION_*` bits.
    pub flags: u32,
    /// Speed along the surface in 3-D, m/s.
    pub speed_3d: f32,
    /// Speed on the 2-D map, m/s.
    pub speed_map: f32,
    /// Direction on the 2-D map, radians from +x towards +y.
    pub direction_map_rad: f32,
    /// Velocity in 3-D, m/s.
    pub velocity_3d: [f32; 3],
    /// Velocity on the map, m/s.
    pub velocity_map: [f32; 2],
    /// Where the contact started, metres.
    pub start_3d: [f32; 3],
    /// Where it is now, metres.
    pub now_3d: [f32; 3],
    /// Where it started on the map, metres.
    pub start_map: [f32; 2],
    /// Where it is now on the map, metres.
    pub now_map: [f32; 2],
    /// Seconds since it started.
    pub duration_s: f32,
}

// The C records are the services' records, byte for byte: what a read
// copies into a C array of them is what the service wrote.
const _: () = {
    assert!(SKINWARE_MAX_CONTACTS == skinware_services::MAX_CONTACTS);
    assert!(SKINWARE_CONTACTS_INPUT_FAULTED == skinware_services::contact_flags::INPUT_FAULTED);
    assert!(SKINWARE_CONTACTS_MORE == skinware_services::contact_flags::MORE_CONTACTS);
    assert!(SKINWARE_MOTION_SLIDING == skinware_services::motion_flags::SLIDING);
    assert!(SKINWARE_MOTION_CONTACT == skinware_services::motion_flags::CONTACT);
    assert!(SKINWARE_MOTION_INPUT_FAULTED == skinware_services::motion_flags::INPUT_FAULTED);
    assert!(size_of::<skinware_contact>() == size_of::<Contact>());
    assert!(offset_of!(skinware_contact, centroid) == offset_of!(Contact, centroid));
    assert!(offset_of!(skinware_contact, map) == offset_of!(Contact, map));
    assert!(offset_of!(skinware_contact, peak) == offset_of!(Contact, peak));
    assert!(size_of::<skinware_region_contacts>() == size_of::<RegionContacts>());
    assert!(offset_of!(skinware_region_contacts, contacts) == offset_of!(RegionContacts, contacts));
    assert!(size_of::<skinware_motion_record>() == size_of::<MotionRecord>());
    assert!(offset_of!(skinware_motion_record, velocity_3d) == offset_of!(MotionRecord, velocity_3d));
    assert!(offset_of!(skinware_motion_record, now_map) == offset_of!(MotionRecord, now_map));
    assert!(offset_of!(skinware_motion_record, duration_s) == offset_of!(MotionRecord, duration_s));
};
