//! `skin pull`: the cable-pull fault injection, on command.
//!
//! Only a virtual skin's layer has a cable that can be pulled: its driver
//! looks for the control file [`skin::config::pull_file`] and fails its
//! acquisitions while it exists. Anything else named here (a layer that is
//! not there, a service, a CAN, EtherCAT or replayed layer) is refused, and
//! no control file is left that nothing would read.

use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use skin::config::drivers::DriverKind;
use skin::driver_status::DriverStatus;
use skinware::ChannelKind;

/// Arguments of `skin pull`.
#[derive(clap::Args)]
pub struct Args {
    /// The layer whose cable to pull (a layer of a `kind = "virtual"` driver).
    layer: String,
    /// The skin.
    #[arg(long, default_value = "default")]
    skin: String,
    /// Plug the cable back in instead.
    #[arg(long)]
    restore: bool,
}

/// How long a layer's driver may take to say what it is: a driver publishes
/// its status right after its layers' channels, so this is only for one
/// caught in between (just started, or restarted).
const STATUS_WAIT: Duration = Duration::from_secs(1);

/// Runs `skin pull`.
pub fn run(args: &Args) -> Result<()> {
    skinware::shm::validate_name("skin", &args.skin)?;
    skinware::shm::validate_name("layer", &args.layer)?;
    let file = skin::config::pull_file(&args.skin, &args.layer);
    if args.restore {
        match std::fs::remove_file(&file) {
            Ok(()) => println!("{}/{}: cable plugged back in", args.skin, args.layer),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                // Nothing to undo; a name that could never have been pulled is still an error.
                check_pullable(&args.skin, &args.layer)?;
                println!("{}/{}: the cable was not pulled", args.skin, args.layer);
            }
            Err(e) => return Err(e).with_context(|| format!("cannot remove {}", file.display())),
        }
        return Ok(());
    }
    check_pullable(&args.skin, &args.layer)?;
    // Replaced whole, never written through a link or into a FIFO that
    // someone left at this name.
    skinware::shm::replace_file(&file, b"pulled\n", 0o644)
        .with_context(|| format!("cannot create {}", file.display()))?;
    println!("{}/{}: cable pulled (undo with --restore)", args.skin, args.layer);
    Ok(())
}

/// Checks that `layer` of `skin` is here and written by a driver whose
/// kind has a simulated cable.
fn check_pullable(skin: &str, layer: &str) -> Result<()> {
    let dir = skinware::shm::segment_dir();
    let channels = skinware::list_skin_channels(&dir, skin)?;
    if !channels.iter().any(|c| c.channel == layer && c.kind == Some(ChannelKind::Layer)) {
        return Err(crate::skins::missing_channel(skin, layer, ChannelKind::Layer))
            .context(format!("cannot pull the cable of {skin}/{layer}"));
    }
    let pullable: Vec<String> = DriverKind::ALL
        .into_iter()
        .filter(|k| k.has_simulated_cables())
        .map(|k| format!("kind = \"{}\"", k.as_str()))
        .collect();
    let pullable = pullable.join(" or ");
    let Some(driver) = driver_of(skin, layer)? else {
        bail!(
            "cannot pull the cable of {skin}/{layer}: no driver of `skin run` says it writes it (its writer, pid {}, \
             is another program); only the layers of {pullable} drivers have a simulated cable",
            channels.iter().find(|c| c.channel == layer).map_or(0, |c| c.writer_pid)
        );
    };
    match DriverKind::from_name(&driver.kind) {
        Some(kind) if kind.has_simulated_cables() => Ok(()),
        kind => bail!(
            "cannot pull the cable of {skin}/{layer}: its driver {} is of kind = \"{}\", which has no simulated cable; \
             only the layers of {pullable} drivers can be pulled{}",
            driver.driver,
            driver.kind,
            match kind {
                Some(DriverKind::Can | DriverKind::Ethercat) => " (a real bus's fault is a real unplugged cable)",
                Some(DriverKind::Replay) => " (a replay plays back the faults it recorded)",
                Some(DriverKind::Ros2) => " (a ros2 layer faults when its topic falls silent: stop its publisher)",
                _ => "",
            }
        ),
    }
}

/// The status of the driver that writes `layer` of `skin`: a live one if
/// there is, else the last one left (a driver being restarted is the same
/// kind as the one that died), waiting [`STATUS_WAIT`] for one to appear.
fn driver_of(skin: &str, layer: &str) -> Result<Option<DriverStatus>> {
    let dir = skinware::shm::segment_dir();
    let started = Instant::now();
    loop {
        let now = skin::driver_status::now_ns();
        let mut writing: Vec<DriverStatus> = skin::driver_status::find(&dir, Some(skin))?
            .into_iter()
            .filter_map(|found| found.status.ok())
            .filter(|status| status.skin == skin && status.layers.iter().any(|l| l == layer))
            .collect();
        writing.sort_by_key(|status| !status.is_live(now));
        if let Some(status) = writing.into_iter().next() {
            return Ok(Some(status));
        }
        if started.elapsed() >= STATUS_WAIT {
            return Ok(None);
        }
        std::thread::sleep(Duration::from_millis(50));
    }
}
