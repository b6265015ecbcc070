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
            let points: Vec<(f64, f64)> =
                records.iter().filter(|r| r.layers == layers).map(|r| (r.apps as f64, pick(r) as f64 / 1e3)).collect();
            draw_line(&mut chart, i, text.then(|| format!("{layers} layer(s)")), points)?;
        }
        if text {
            draw_legend(&mut chart, SeriesLabelPosition::MiddleRight)?;
        }
    }
    root.present().map_err(|e| anyhow!("plot: {e}"))?;
    Ok(())
}

/// `skin bench scale`: what one frame costs and the CPU it takes, against
/// the skin's taxels, on log-log axes, at 1 kHz (or the sweep's first rate)
/// with the most readers of the sweep.
pub fn scale(points: &[crate::scale_record::ScalePoint], path: &Path) -> Result<()> {
    let text = register_font();
    let rate =
        if points.iter().any(|p| p.rate_hz == 1000.0) { 1000.0 } else { points.first().map_or(0.0, |p| p.rate_hz) };
    let readers = points.iter().map(|p| p.readers).max().unwrap_or(0);
    let at = |readers: usize| -> Vec<&crate::scale_record::ScalePoint> {
        points.iter().filter(|p| p.rate_hz == rate && p.readers == readers).collect()
    };
    let loaded = at(readers);
    let root = BitMapBackend::new(path, (1400, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow!("plot: {e}"))?;
    let halves = root.split_evenly((1, 2));
    type Pick = fn(&crate::scale_record::ScalePoint) -> f64;
    let time_series: Vec<(&str, Pick)> = vec![
        ("publish p50", |p| (p.publish_ns.p50 as f64 / 1e3).max(0.01)),
        ("publish p99", |p| (p.publish_ns.p99 as f64 / 1e3).max(0.01)),
        ("memcpy p50", |p| (p.memcpy_ns.p50 as f64 / 1e3).max(0.01)),
        ("waiting reader's copy p50", |p| (p.waiting_copy_ns.p50 as f64 / 1e3).max(0.01)),
        ("acquisition to waiting reader p50", |p| (p.waiting_latency_ns.p50 as f64 / 1e3).max(0.01)),
    ];
    let cpu_series: Vec<(&str, Pick)> = vec![
        ("writer thread", |p| p.writer_thread_cpu_percent.max(0.01)),
        ("writer's ringer", |p| p.writer_helpers_cpu_percent.max(0.01)),
        ("all readers", |p| p.readers_cpu_percent.max(0.01)),
    ];
    let panels = [
        (format!("{rate} Hz, {readers} readers: microseconds per frame"), "microseconds", time_series),
        (format!("{rate} Hz, {readers} readers: CPU, % of one core"), "% of one core", cpu_series),
    ];
    for (area, (title, unit, series)) in halves.iter().zip(panels) {
        let values: Vec<f64> = series.iter().flat_map(|(_, pick)| loaded.iter().map(|p| pick(p))).collect();
        let top = values.iter().copied().fold(1.0, f64::max) * 2.0;
        let bottom = values.iter().copied().fold(f64::INFINITY, f64::min).min(top / 10.0) / 2.0;
        let mut builder = ChartBuilder::on(area);
        builder.margin(20).x_label_area_size(40).y_label_area_size(60);
        if text {
            builder.caption(&title, ("sans-serif", 20));
        }
        let mut chart = builder
            .build_cartesian_2d((5_000f64..2_000_000f64).log_scale(), (bottom.max(1e-3)..top).log_scale())
            .map_err(|e| anyhow!("plot: {e}"))?;
        let mut mesh = chart.configure_mesh();
        if text {
            mesh.x_desc("taxels").y_desc(unit);
        } else {
            mesh.x_labels(0).y_labels(0);
        }
        mesh.draw().map_err(|e| anyhow!("plot: {e}"))?;
        for (i, (name, pick)) in series.iter().enumerate() {
            let line: Vec<(f64, f64)> = loaded.iter().map(|p| (p.taxels as f64, pick(p))).collect();
            draw_line(&mut chart, i, text.then(|| (*name).to_owned()), line)?;
        }
        if text {
            draw_legend(&mut chart, SeriesLabelPosition::UpperLeft)?;
        }
    }
    root.present().map_err(|e| anyhow!("plot: {e}"))?;
    Ok(())
}

/// Draws `points` as a line with a dot at each, in the palette's `index`th
/// colour, with `label` in the legend if given.
fn draw_line<'a, DB: DrawingBackend + 'a, X: Ranged<ValueType = f64>, Y: Ranged<ValueType = f64>>(
    chart: &mut ChartContext<'a, DB, Cartesian2d<X, Y>>,
    index: usize,
    label: Option<String>,
    points: Vec<(f64, f64)>,
) -> Result<()> {
    let color = Palette99::pick(index).to_rgba();
    let drawn = chart
        .draw_series(LineSeries::new(points.clone(), color.stroke_width(2)))
        .map_err(|e| anyhow!("plot: {e:?}"))?;
    if let Some(label) = label {
        drawn.label(label).legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2)));
    }
    chart.draw_series(points.iter().map(|&p| Circle::new(p, 3, color.filled()))).map_err(|e| anyhow!("plot: {e:?}"))?;
    Ok(())
}

/// Draws the legend of `chart`'s labelled lines at `position`.
fn draw_legend<'a, DB: DrawingBackend + 'a, X: Ranged<ValueType = f64>, Y: Ranged<ValueType = f64>>(
    chart: &mut ChartContext<'a, DB, Cartesian2d<X, Y>>,
    position: SeriesLabelPosition,
) -> Result<()> {
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .draw()
        .map_err(|e| anyhow!("plot: {e:?}"))
}
