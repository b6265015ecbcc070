//! `skin ls`: the tree of layers, patches, modules and sensor counts.

use std::io::Write;
use std::time::Duration;

use anyhow::Result;
use skinware::ChannelKind;

/// Arguments of `skin ls`.
#[derive(clap::Args)]
pub struct Args {
    /// Only this skin.
    #[arg(long)]
    skin: Option<String>,
    /// Print JSON for scripts.
    #[arg(long)]
    json: bool,
    /// Also list every patch of each layer with its module and sensor counts.
    #[arg(long, short = 'p')]
    patches: bool,
    /// Also list every patch, and every module with its sensor count.
    #[arg(long)]
    modules: bool,
    /// List the regions and sub-regions instead (from the published geometry).
    #[arg(long)]
    regions: bool,
    #[command(flatten)]
    remote: super::bridge::RemoteArgs,
}

/// How long `skin ls` watches the writers to time their rates: a dozen
/// frames of a 40 Hz layer, timed by the writer's own clock (see
/// `layers::rate_between`), and still an answer at once.
const RATE_WINDOW: Duration = Duration::from_millis(300);

/// Runs `skin ls`.
pub fn run(args: &Args) -> Result<()> {
    if args.remote.remote.is_some() {
        return super::bridge::ls(&args.remote, args.skin.as_deref(), args.json);
    }
    if args.regions {
        return regions(args);
    }
    let sampled =
        crate::layers::sample_channels(args.skin.as_deref(), &[ChannelKind::Layer, ChannelKind::Service], RATE_WINDOW)?;
    if let Some(skin) = args.skin.as_deref()
        && sampled.is_empty()
        && skinware::list_skin_channels(&skinware::shm::segment_dir(), skin)?.is_empty()
    {
        return Err(crate::skins::missing_skin(skin));
    }
    let (layers, services): (Vec<_>, Vec<_>) =
        sampled.into_iter().partition(|s| s.info.kind == Some(ChannelKind::Layer));
    let mut layers = crate::layers::reports(layers);
    let services = super::services::reports(services);
    let drivers = crate::layers::driver_statuses(args.skin.as_deref())?;
    crate::layers::attach_devices(&mut layers, &drivers);
    let mut out = std::io::stdout().lock();
    if args.json {
        let listing = serde_json::json!({ "layers": layers, "services": services, "drivers": drivers });
        serde_json::to_writer_pretty(&mut out, &listing)?;
        writeln!(out)?;
        return Ok(());
    }
    if layers.is_empty() && services.is_empty() {
        writeln!(
            out,
            "no skin runs here (channels are in {}); {}",
            skinware::shm::segment_dir().display(),
            crate::skins::HOW_TO_START
        )?;
    }
    for layer in &layers {
        write_layer(&mut out, layer, args)?;
    }
    for service in &services {
        writeln!(out, "{}", super::services::describe(service))?;
    }
    write_drivers(&mut out, &drivers, &layers)
}

/// A layer's line, its device's, and its patches' and modules' if asked.
fn write_layer(out: &mut impl Write, layer: &crate::layers::LayerReport, args: &Args) -> Result<()> {
    writeln!(
        out,
        "{}/{}  [{}]  {} sensors ({}), {} modules, {} patches, {:.1} Hz measured ({:.1} nominal), {} overruns",
        layer.skin,
        layer.name,
        layer.state,
        layer.sensors,
        layer.sensor_type,
        layer.modules,
        layer.patches,
        layer.rate_hz,
        layer.nominal_rate_hz,
        layer.overruns
    )?;
    if let Some(device) = &layer.device {
        writeln!(out, "  {}", describe_device(device))?;
    }
    if !(args.patches || args.modules) {
        return Ok(());
    }
    for (patch, modules) in &layer.tree {
        let sensors: usize = modules.iter().map(|(_, n)| n).sum();
        writeln!(out, "  patch {patch}: {} modules, {sensors} sensors", modules.len())?;
        if args.modules {
            for (module, count) in modules {
                writeln!(out, "    module {module}: {count} sensors")?;
            }
        }
    }
    Ok(())
}

/// A line per driver with devices of its own (an EtherCAT bus), and its
/// devices whose layers have no channel. Drivers without devices (virtual,
/// CAN, replay) are said by their layers' lines; they show in --json.
fn write_drivers(
    out: &mut impl Write,
    drivers: &[skin::driver_status::DriverStatus],
    layers: &[crate::layers::LayerReport],
) -> Result<()> {
    for driver in drivers.iter().filter(|d| !d.devices.is_empty() || d.bus_fault.is_some()) {
        let bus = driver.bus_fault.as_deref().map_or_else(|| "bus up".to_owned(), |why| format!("bus not up: {why}"));
        let in_op = driver.devices.iter().filter(|d| d.state == "OP").count();
        writeln!(
            out,
            "driver {}/{} ({}, pid {}): {bus}, {in_op} of {} SubDevices in OP",
            driver.skin,
            driver.driver,
            driver.kind,
            driver.pid,
            driver.devices.len()
        )?;
        // A device whose layer has no channel (yet) is shown here, not under its layer.
        for device in &driver.devices {
            if !layers.iter().any(|l| l.skin == driver.skin && l.name == device.layer) {
                writeln!(out, "  (layer {} not published) {}", device.layer, describe_device(device))?;
            }
        }
    }
    Ok(())
}

/// One line on a device, e.g. `SubDevice 0 "SKIN-T708": vendor 0x00534b4e
/// product 0x00007ac7 rev 0x00000001 serial 1, OP, newest sample 0.3 ms ago,
/// 52311 good cycles, 0 faults`. Identities in hex, as EtherCAT tools and
/// device descriptions (ESI) write them.
fn describe_device(device: &skin::driver_status::DeviceStatus) -> String {
    let hex = |v: Option<u32>| v.map_or_else(|| "?".to_owned(), |v| format!("{v:#010x}"));
    let state = if device.state.is_empty() { "state not read yet" } else { &device.state };
    let age =
        device.sample_age_ms.map_or_else(|| "no sample yet".to_owned(), |ms| format!("newest sample {ms:.1} ms ago"));
    let fault = device.fault.as_deref().map(|why| format!(", faulted: {why}")).unwrap_or_default();
    format!(
        "SubDevice {} {:?}: vendor {} product {} rev {} serial {}, {state}, {age}, {} good cycles, {} faults{fault}",
        device.position,
        device.name,
        hex(device.vendor_id),
        hex(device.product_code),
        hex(device.revision),
        device.serial.map_or_else(|| "?".to_owned(), |v| v.to_string()),
        device.cycles,
        device.faults
    )
}

fn regions(args: &Args) -> Result<()> {
    let skin = args.skin.as_deref().unwrap_or("default");
    let geometry = skinware_geometry::SkinGeometry::open(skin).map_err(|e| crate::skins::missing_geometry(skin, e))?;
    let r = &geometry.regions;
    let mut out = std::io::stdout().lock();
    if args.json {
        let regions: Vec<_> = (0..r.names.len())
            .map(|k| {
                serde_json::json!({
                    "name": r.names[k],
                    "sensors": r.sensors[k].len(),
                    "subregions": r.subregions_of[k],
                })
            })
            .collect();
        let subregions: Vec<_> = (0..r.subregion_sensors.len())
            .map(|k| {
                serde_json::json!({
                    "id": k,
                    "sensors": r.subregion_sensors[k].len(),
                    "regions": r.regions_of[k].iter().map(|&g| &r.names[g as usize]).collect::<Vec<_>>(),
                })
            })
            .collect();
        serde_json::to_writer_pretty(
            &mut out,
            &serde_json::json!({ "skin": skin, "regions": regions, "subregions": subregions }),
        )?;
        writeln!(out)?;
        return Ok(());
    }
    if r.names.is_empty() {
        writeln!(out, "skin {skin}: no regions; add [[region]] tables to the config (see examples/README.md)")?;
    }
    for k in 0..r.names.len() {
        let subs: Vec<String> = r.subregions_of[k].iter().map(|s| format!("#{s}")).collect();
        writeln!(out, "region {}: {} sensors, sub-regions {}", r.names[k], r.sensors[k].len(), subs.join(" "))?;
    }
    for k in 0..r.subregion_sensors.len() {
        let names: Vec<&str> = r.regions_of[k].iter().map(|&g| r.names[g as usize].as_str()).collect();
        writeln!(out, "  sub-region #{k}: {} sensors, in {}", r.subregion_sensors[k].len(), names.join(", "))?;
    }
    Ok(())
}
