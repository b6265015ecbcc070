//! The PNG plots, laid out like the paper's figures.

use std::path::Path;

use anyhow::{Result, anyhow};
use plotters::prelude::*;

use crate::paper_record::PaperRecord;

const FONT_PATHS: [&str; 3] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
];

/// Registers a system font for labels; `false` if none is installed (the
/// plot is then drawn without text).
fn register_font() -> bool {
    static REGISTERED: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *REGISTERED.get_or_init(|| {
        for path in FONT_PATHS {
            if let Ok(bytes) = std::fs::read(path) {
                let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                if plotters::style::register_font("sans-serif", FontStyle::Normal, bytes).is_ok() {
                    return true;
                }
            }
        }
        false
    })
}

/// Fig. 6: worst-case time against the number of apps, one line per layer
/// count; writers on the left, readers on the right.
pub fn fig6(records: &[PaperRecord], path: &Path) -> Result<()> {
    let text = register_font();
    let root = BitMapBackend::new(path, (1400, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow!("plot: {e}"))?;
    let halves = root.split_evenly((1, 2));
    let mut layer_counts: Vec<usize> = records.iter().map(|r| r.layers).collect();
    layer_counts.dedup();
    let max_apps = records.iter().map(|r| r.apps).max().unwrap_or(1) as f64;
    for (area, (title, pick)) in halves.iter().zip([
        ("writers: worst case (us)", (|r: &PaperRecord| r.writer_ns.max) as fn(&PaperRecord) -> u64),
        ("readers: worst case (us)", |r: &PaperRecord| r.reader_ns.max),
    ]) {
        let top = records.iter().map(|r| pick(r) as f64 / 1e3).fold(1.0, f64::max) * 1.1;
        let mut builder = ChartBuilder::on(area);
        builder.margin(20).x_label_area_size(40).y_label_area_size(60);
        if text {
            builder.caption(title, ("sans-serif", 22));
        }
        let mut chart = builder.build_cartesian_2d(0.5..max_apps + 0.5, 0.0..top).map_err(|e| anyhow!("plot: {e}"))?;
        let mut mesh = chart.configure_mesh();
        if text {
            mesh.x_desc("applications").y_desc("microseconds");
        } else {
            mesh.x_labels(0).y_labels(0);
        }
        mesh.draw().map_err(|e| anyhow!("plot: {e}"))?;
        for (i, &layers) in layer_counts.iter().enumerate() {
            let color = Palette99::pick(i).to_rgba();
            let points: Vec<(f64, f64)> =
                records.iter().filter(|r| r.layers == layers).map(|r| (r.apps as f64, pick(r) as f64 / 1e3)).collect();
            let series = chart
                .draw_series(LineSeries::new(points.clone(), color.stroke_width(2)))
                .map_err(|e| anyhow!("plot: {e}"))?;
            if text {
                series
                    .label(format!("{layers} layer(s)"))
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2)));
            }
            chart
                .draw_series(points.iter().map(|&p| Circle::new(p, 3, color.filled())))
                .map_err(|e| anyhow!("plot: {e}"))?;
        }
        if text {
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .draw()
                .map_err(|e| anyhow!("plot: {e}"))?;
        }
    }
    root.present().map_err(|e| anyhow!("plot: {e}"))?;
    Ok(())
}
