//! `skin geometry`: what the geometry pipeline made of the skin, and how well.

use std::io::Write;
use std::path::PathBuf;

use anyhow::Result;
use skinware_geometry::SkinGeometry;

/// Arguments of `skin geometry`.
#[derive(clap::Args)]
pub struct Args {
    /// Compute (or take from the cache) the geometry of this config instead of
    /// reading the one published by a running `skin run`.
    config: Option<PathBuf>,
    /// The skin whose published geometry to read.
    #[arg(long, default_value = "default")]
    skin: String,
    /// Print JSON for scripts.
    #[arg(long)]
    json: bool,
}

/// Runs `skin geometry`.
pub fn run(args: &Args) -> Result<()> {
    let (geometry, source) = match &args.config {
        Some(path) => {
            let config = skin::config::Config::load(path)?;
            let (geometry, cached) = crate::geometry::load_or_build(&config)?;
            (geometry, if cached { "cache" } else { "computed now" })
        }
        None => {
            (SkinGeometry::open(&args.skin).map_err(|e| crate::skins::missing_geometry(&args.skin, e))?, "published")
        }
    };
    let mut out = std::io::stdout().lock();
    if args.json {
        serde_json::to_writer_pretty(&mut out, &summary(&geometry, source))?;
        writeln!(out)?;
        return Ok(());
    }
    let s = &geometry.neighbour_stats;
    let q = &geometry.map.quality;
    let t = &geometry.build_times;
    writeln!(
        out,
        "skin {}: {} sensors on {} layers, {} links, {} regions ({} sub-regions)",
        geometry.skin,
        geometry.sensor_count(),
        geometry.layers.len(),
        geometry.links.len(),
        geometry.regions.names.len(),
        geometry.regions.subregion_sensors.len()
    )?;
    writeln!(
        out,
        "neighbour graph: {} edges; neighbours per sensor min {} mean {:.2} max {}; {} isolated; edge length mean {:.2} mm, max {:.2} mm",
        s.edges,
        s.min_degree,
        s.mean_degree,
        s.max_degree,
        s.isolated,
        s.mean_edge_m * 1e3,
        s.max_edge_m * 1e3
    )?;
    writeln!(out, "2-D map: discrete exponential map per surface piece, {} pieces", q.pieces)?;
    writeln!(
        out,
        "  neighbour-distance error: mean {:.3} %, p95 {:.3} %",
        q.mean_relative_error * 100.0,
        q.p95_relative_error * 100.0
    )?;
    writeln!(
        out,
        "  seam edges {:.2} %; flipped triangles {:.3} % of {}; stacked sensors {:.3} %; pieces overlap: {}",
        q.seam_edge_fraction * 100.0,
        q.flipped_fraction * 100.0,
        q.triangles,
        q.stacked_fraction * 100.0,
        if q.pieces_overlap { "YES" } else { "no" }
    )?;
    writeln!(
        out,
        "built in {:.0} ms (indices {:.0}, regions {:.0}, neighbours {:.0}, map {:.0}); this copy: {source}",
        t.total_ms, t.indices_ms, t.regions_ms, t.neighbours_ms, t.map_ms
    )?;
    Ok(())
}

fn summary(geometry: &SkinGeometry, source: &str) -> serde_json::Value {
    let s = &geometry.neighbour_stats;
    let q = &geometry.map.quality;
    let t = &geometry.build_times;
    serde_json::json!({
        "skin": geometry.skin,
        "sensors": geometry.sensor_count(),
        "layers": geometry.layers.iter().map(|l| &l.name).collect::<Vec<_>>(),
        "links": geometry.links,
        "regions": geometry.regions.names.len(),
        "subregions": geometry.regions.subregion_sensors.len(),
        "neighbours": {
            "edges": s.edges, "min_degree": s.min_degree, "mean_degree": s.mean_degree,
            "max_degree": s.max_degree, "isolated": s.isolated,
            "mean_edge_m": s.mean_edge_m, "max_edge_m": s.max_edge_m,
        },
        "map": {
            "method": "discrete exponential map",
            "pieces": q.pieces,
            "mean_relative_error": q.mean_relative_error,
            "p95_relative_error": q.p95_relative_error,
            "seam_edge_fraction": q.seam_edge_fraction,
            "triangles": q.triangles,
            "flipped_fraction": q.flipped_fraction,
            "stacked_fraction": q.stacked_fraction,
            "pieces_overlap": q.pieces_overlap,
        },
        "build_ms": {
            "indices": t.indices_ms, "regions": t.regions_ms, "neighbours": t.neighbours_ms,
            "map": t.map_ms, "total": t.total_ms,
        },
        "source": source,
    })
}
