//! `skin ls`: the tree of layers, patches, modules and sensor counts.

use std::io::Write;
use std::time::Duration;

use anyhow::Result;

/// Arguments of `skin ls`.
#[derive(clap::Args)]
pub struct Args {
    /// Only this skin.
    #[arg(long)]
    skin: Option<String>,
    /// Print JSON for scripts.
    #[arg(long)]
    json: bool,
    /// Also list every module with its sensor count.
    #[arg(long)]
    modules: bool,
}

/// Runs `skin ls`.
pub fn run(args: &Args) -> Result<()> {
    let layers = crate::layers::gather(args.skin.as_deref(), Duration::from_millis(300))?;
    let mut out = std::io::stdout().lock();
    if args.json {
        serde_json::to_writer_pretty(&mut out, &serde_json::json!({ "layers": layers }))?;
        writeln!(out)?;
        return Ok(());
    }
    if layers.is_empty() {
        writeln!(out, "no layers (is `skin run` running? channels are in {})", skinware::shm::segment_dir().display())?;
    }
    for layer in &layers {
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
        for (patch, modules) in &layer.tree {
            let sensors: usize = modules.iter().map(|(_, n)| n).sum();
            writeln!(out, "  patch {patch}: {} modules, {sensors} sensors", modules.len())?;
            if args.modules {
                for (module, count) in modules {
                    writeln!(out, "    module {module}: {count} sensors")?;
                }
            }
        }
    }
    Ok(())
}
