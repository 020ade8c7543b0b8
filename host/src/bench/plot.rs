//! Line charts and stacked bar charts as PNG files (benchmark reports: error against time,
//! time per frame split by stage, and the like).
//!
//! Drawn with `plotters` into an RGB buffer and encoded with `image`; text uses DejaVu Sans
//! embedded in the binary (the `dejavu` crate), so no system font, fontconfig or freetype is needed.

use std::ops::Range;
use std::path::Path;
use std::sync::OnceLock;

use anyhow::{anyhow, ensure, Context, Result};
use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::prelude::*;

/// One curve: a name for the legend and its (x, y) points, in order.
pub struct Series {
    /// Legend entry; an empty name gets no legend entry.
    pub name: String,
    /// The points, joined by lines in this order.
    pub points: Vec<(f64, f64)>,
}

/// Axis scale.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Scale {
    /// Evenly spaced values.
    Linear,
    /// Evenly spaced powers of ten; only positive values can be shown.
    Log,
}

/// A chart: title, axis labels and scales.
pub struct Chart<'a> {
    /// Title drawn above the plot.
    pub title: &'a str,
    /// Label of the horizontal axis.
    pub x_label: &'a str,
    /// Label of the vertical axis.
    pub y_label: &'a str,
    /// Scale of the horizontal axis.
    pub x_scale: Scale,
    /// Scale of the vertical axis.
    pub y_scale: Scale,
}

/// Series colours, in order (the Tableau 10 palette, as 0xRRGGBB); series past ten reuse them.
const PALETTE: [u32; 10] = [
    0x1f77b4, 0xff7f0e, 0x2ca02c, 0xd62728, 0x9467bd, 0x8c564b, 0xe377c2, 0x7f7f7f, 0xbcbd22, 0x17becf,
];

/// Registers the embedded font as plotters' "sans-serif" family, once per process.
fn ensure_font() -> Result<()> {
    static FONT: OnceLock<bool> = OnceLock::new();
    let ok = FONT.get_or_init(|| {
        plotters::style::register_font("sans-serif", FontStyle::Normal, dejavu::sans::regular()).is_ok()
    });
    ensure!(*ok, "the embedded DejaVu Sans font could not be loaded");
    Ok(())
}

/// Draws `series` as lines with point markers into a `width` x `height` PNG at `path`, with a legend.
/// Axis ranges come from the data (log axes: only positive finite values; points that are not are skipped;
/// a padded range when all values are equal). Errors (anyhow::Result) name the file.
pub fn line_chart(path: &Path, chart: &Chart, series: &[Series], width: u32, height: u32) -> Result<()> {
    render(path, chart, series, width, height).with_context(|| format!("writing plot {}", path.display()))
}

/// [`line_chart`] without the file name in its errors.
fn render(path: &Path, chart: &Chart, series: &[Series], width: u32, height: u32) -> Result<()> {
    ensure!(
        width >= 100 && height >= 100,
        "plot size {width}x{height} is below 100x100"
    );
    ensure_font()?;
    let keep = |v: f64, s: Scale| v.is_finite() && (s == Scale::Linear || v > 0.0);
    let ok = |p: &(f64, f64)| keep(p.0, chart.x_scale) && keep(p.1, chart.y_scale);
    let curves: Vec<Vec<_>> = series
        .iter()
        .map(|s| s.points.iter().copied().filter(ok).collect())
        .collect();
    let all = || curves.iter().flatten();
    ensure!(
        all().next().is_some(),
        "no point to draw (log axes show only positive finite values)"
    );
    let xr = range(all().map(|p| p.0), chart.x_scale);
    let yr = range(all().map(|p| p.1), chart.y_scale);

    let mut buf = vec![255u8; width as usize * height as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (width, height)).into_drawing_area();
        let (lin_x, lin_y, log_x, log_y) = (xr.clone(), yr.clone(), xr.clone().log_scale(), yr.clone().log_scale());
        match (chart.x_scale, chart.y_scale) {
            (Scale::Linear, Scale::Linear) => draw(&root, chart, series, &curves, (lin_x, xr), (lin_y, yr)),
            (Scale::Linear, Scale::Log) => draw(&root, chart, series, &curves, (lin_x, xr), (log_y, yr)),
            (Scale::Log, Scale::Linear) => draw(&root, chart, series, &curves, (log_x, xr), (lin_y, yr)),
            (Scale::Log, Scale::Log) => draw(&root, chart, series, &curves, (log_x, xr), (log_y, yr)),
        }?;
        root.present().map_err(|e| anyhow!("{e}"))?;
    }
    let img = image::RgbImage::from_raw(width, height, buf).context("plot buffer has the wrong size")?;
    Ok(img.save_with_format(path, image::ImageFormat::Png)?)
}

/// The axis range for `values` (not empty): a little padding, and a wider one when all are equal.
/// A log range holding fewer than two powers of ten grows to whole decades, so that it has labels.
fn range(values: impl Iterator<Item = f64>, scale: Scale) -> Range<f64> {
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), v| (l.min(v), h.max(v)));
    match scale {
        Scale::Log => {
            let pad = if lo == hi { 2.0 } else { (hi / lo).powf(0.03) };
            let (lo, hi) = (lo / pad, hi * pad);
            let (dlo, dhi) = (lo.log10().floor(), hi.log10().ceil());
            // (The 0.1% margin keeps plotters from losing the end decades to rounding.)
            if dhi - dlo < 3.0 {
                10f64.powf(dlo) / 1.001..10f64.powf(dhi) * 1.001
            } else {
                lo..hi
            }
        }
        Scale::Linear if lo == hi => {
            let pad = if lo == 0.0 { 1.0 } else { lo.abs() * 0.1 };
            lo - pad..hi + pad
        }
        Scale::Linear => {
            let pad = (hi - lo) * 0.03;
            lo - pad..hi + pad
        }
    }
}

/// Draws the whole chart on `root` with the given axis coordinates.
fn draw<X, Y>(
    root: &DrawingArea<BitMapBackend, plotters::coord::Shift>,
    chart: &Chart,
    series: &[Series],
    curves: &[Vec<(f64, f64)>],
    (x, xr): (X, Range<f64>),
    (y, yr): (Y, Range<f64>),
) -> Result<()>
where
    X: AsRangedCoord<Value = f64>,
    Y: AsRangedCoord<Value = f64>,
    X::CoordDescType: ValueFormatter<f64>,
    Y::CoordDescType: ValueFormatter<f64>,
{
    let e = |e: DrawingAreaErrorKind<_>| anyhow!("{e}");
    root.fill(&WHITE).map_err(e)?;
    // 24 px, smaller where a long title (a GPU's and driver's names) would not fit the width.
    let width = root.dim_in_pixel().0 as f64;
    let size = 24.0f64.min(1.6 * width / chart.title.chars().count().max(1) as f64);
    let mut cc = ChartBuilder::on(root)
        .caption(chart.title, ("sans-serif", size))
        .margin(16)
        .x_label_area_size(50)
        .y_label_area_size(80)
        .build_cartesian_2d(x, y)
        .map_err(e)?;
    cc.configure_mesh()
        .x_desc(chart.x_label)
        .y_desc(chart.y_label)
        .axis_desc_style(("sans-serif", 17))
        .label_style(("sans-serif", 14))
        .x_label_formatter(&|v| tick(*v))
        .y_label_formatter(&|v| tick(*v))
        .light_line_style(RGBColor(235, 235, 235))
        .bold_line_style(RGBColor(200, 200, 200))
        .draw()
        .map_err(e)?;
    for (i, (s, pts)) in series.iter().zip(curves).enumerate() {
        let c = PALETTE[i % PALETTE.len()];
        let color = RGBColor((c >> 16) as u8, (c >> 8) as u8, c as u8);
        let line = cc
            .draw_series(LineSeries::new(pts.iter().copied(), color.stroke_width(2)))
            .map_err(e)?;
        if !s.name.is_empty() {
            line.label(s.name.as_str())
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 24, y)], color.stroke_width(3)));
        }
        cc.draw_series(pts.iter().map(|&p| Circle::new(p, 3, color.filled())))
            .map_err(e)?;
    }
    cc.configure_series_labels()
        .position(legend_corner(chart, curves, &xr, &yr))
        .label_font(("sans-serif", 15))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .draw()
        .map_err(e)?;
    Ok(())
}

/// The legend corner that covers the fewest points and line samples (upper right on ties).
fn legend_corner(chart: &Chart, curves: &[Vec<(f64, f64)>], xr: &Range<f64>, yr: &Range<f64>) -> SeriesLabelPosition {
    let norm = |v: f64, r: &Range<f64>, s: Scale| match s {
        Scale::Linear => (v - r.start) / (r.end - r.start),
        Scale::Log => (v / r.start).ln() / (r.end / r.start).ln(),
    };
    let n = |&(x, y): &(f64, f64)| (norm(x, xr, chart.x_scale), norm(y, yr, chart.y_scale));
    let mut samples = vec![];
    for c in curves.iter().map(|c| c.iter().map(n).collect::<Vec<_>>()) {
        let lerp = |(a, b): ((f64, f64), (f64, f64)), t: f64| (a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1));
        let segments = c.windows(2).map(|w| (w[0], w[1]));
        samples.extend(segments.flat_map(|ab| (0..8).map(move |i| lerp(ab, i as f64 / 8.0))));
        samples.extend(c.last());
    }
    let corners = [
        (SeriesLabelPosition::UpperRight, true, true),
        (SeriesLabelPosition::UpperLeft, false, true),
        (SeriesLabelPosition::LowerRight, true, false),
        (SeriesLabelPosition::LowerLeft, false, false),
    ];
    let covered = |right: bool, upper: bool| {
        samples
            .iter()
            .filter(|&&(x, y)| (if right { x > 0.6 } else { x < 0.4 }) && (if upper { y > 0.7 } else { y < 0.3 }))
            .count()
    };
    corners
        .into_iter()
        .min_by_key(|&(_, r, u)| covered(r, u))
        .map_or(SeriesLabelPosition::UpperRight, |c| c.0)
}

/// A short tick label: plain decimals for moderate values, else scientific notation.
fn tick(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && !(1e-3..1e5).contains(&a) {
        let s = format!("{v:.1e}");
        s.replace(".0e", "e")
    } else {
        let s = format!("{v:.4}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    }
}

/// One bar of [`stacked_bars`]: its label under the axis and its parts' heights, bottom first.
pub struct Bar {
    pub label: String,
    pub parts: Vec<f64>,
}

/// Draws `bars` as stacked bars (part `k` of every bar in colour `k`, named `parts[k]` in the
/// legend) into a `width` x `height` PNG at `path`. Errors name the file.
pub fn stacked_bars(
    path: &Path,
    title: &str,
    y_label: &str,
    parts: &[&str],
    bars: &[Bar],
    width: u32,
    height: u32,
) -> Result<()> {
    draw_bars(path, title, y_label, parts, bars, width, height)
        .with_context(|| format!("writing plot {}", path.display()))
}

fn draw_bars(
    path: &Path,
    title: &str,
    y_label: &str,
    parts: &[&str],
    bars: &[Bar],
    width: u32,
    height: u32,
) -> Result<()> {
    ensure!(!bars.is_empty(), "no bar to draw");
    ensure!(
        bars.iter().flat_map(|b| &b.parts).all(|v| v.is_finite() && *v >= 0.0),
        "bar heights must be finite and not negative"
    );
    ensure_font()?;
    let top = bars
        .iter()
        .map(|b| b.parts.iter().sum::<f64>())
        .fold(0.0, f64::max)
        .max(1e-9)
        * 1.1;
    let mut buf = vec![255u8; width as usize * height as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (width, height)).into_drawing_area();
        let e = |e: DrawingAreaErrorKind<_>| anyhow!("{e}");
        root.fill(&WHITE).map_err(e)?;
        let size = 24.0f64.min(1.6 * width as f64 / title.chars().count().max(1) as f64);
        let n = bars.len();
        let mut cc = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", size))
            .margin(16)
            .x_label_area_size(60)
            .y_label_area_size(80)
            .build_cartesian_2d(-0.5f64..n as f64 - 0.5, 0.0..top)
            .map_err(e)?;
        let label = |v: &f64| {
            let i = v.round();
            if (v - i).abs() < 1e-6 && i >= 0.0 && (i as usize) < n {
                bars[i as usize].label.clone()
            } else {
                String::new()
            }
        };
        cc.configure_mesh()
            .disable_x_mesh()
            .x_labels(n)
            .x_label_formatter(&label)
            .y_desc(y_label)
            .axis_desc_style(("sans-serif", 17))
            .label_style(("sans-serif", 13))
            .y_label_formatter(&|v| tick(*v))
            .light_line_style(RGBColor(235, 235, 235))
            .bold_line_style(RGBColor(200, 200, 200))
            .draw()
            .map_err(e)?;
        for (k, name) in parts.iter().enumerate() {
            let c = PALETTE[k % PALETTE.len()];
            let color = RGBColor((c >> 16) as u8, (c >> 8) as u8, c as u8);
            let rects = bars.iter().enumerate().map(|(i, b)| {
                let below: f64 = b.parts.iter().take(k).sum();
                let h = b.parts.get(k).copied().unwrap_or(0.0);
                let x = i as f64;
                Rectangle::new([(x - 0.35, below), (x + 0.35, below + h)], color.filled())
            });
            cc.draw_series(rects)
                .map_err(e)?
                .label(*name)
                .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 14, y + 6)], color.filled()));
        }
        cc.configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .label_font(("sans-serif", 15))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()
            .map_err(e)?;
        root.present().map_err(|e| anyhow!("{e}"))?;
    }
    let img = image::RgbImage::from_raw(width, height, buf).context("plot buffer has the wrong size")?;
    Ok(img.save_with_format(path, image::ImageFormat::Png)?)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn log_log() -> Chart<'static> {
        Chart {
            title: "Error against time",
            x_label: "time (s)",
            y_label: "RMSE",
            x_scale: Scale::Log,
            y_scale: Scale::Log,
        }
    }

    #[test]
    fn log_log_chart_with_two_series_is_a_png() {
        let path = std::env::temp_dir().join(format!("plot_test_{}_loglog.png", std::process::id()));
        let a = Series {
            name: "wavefront".into(),
            points: (0..8).map(|i| (0.01 * 2f64.powi(i), 0.5 / 2f64.powi(i))).collect(),
        };
        let b = Series {
            name: "megakernel".into(),
            points: (0..8).map(|i| (0.02 * 2f64.powi(i), 0.4 / 1.5f64.powi(i))).collect(),
        };
        line_chart(&path, &log_log(), &[a, b], 900, 600).expect("chart is drawn");
        let img = image::open(&path).expect("PNG decodes").to_rgb8();
        assert_eq!(img.dimensions(), (900, 600));
        let first = img.get_pixel(0, 0);
        assert!(img.pixels().any(|p| p != first), "image is one flat colour");
        let _ = std::fs::remove_file(&path);
    }

    #[test]
    fn log_axis_skips_non_positive_points_or_errors_naming_the_file() {
        let path = std::env::temp_dir().join(format!("plot_test_{}_nonpos.png", std::process::id()));
        let mixed = Series {
            name: "mixed".into(),
            points: vec![(0.0, 1.0), (1.0, -2.0), (2.0, 0.5), (f64::NAN, 1.0), (4.0, 0.25)],
        };
        line_chart(&path, &log_log(), &[mixed], 900, 600).expect("bad points are skipped");
        assert_eq!(
            image::open(&path).expect("PNG decodes").to_rgb8().dimensions(),
            (900, 600)
        );

        let none = Series {
            name: "bad".into(),
            points: vec![(0.0, 1.0), (-1.0, 2.0)],
        };
        let err = line_chart(&path, &log_log(), &[none], 900, 600).expect_err("nothing to draw");
        let msg = format!("{err:#}");
        assert!(
            msg.contains(&path.display().to_string()) && msg.contains("positive"),
            "{msg}"
        );
        let _ = std::fs::remove_file(&path);
    }

    #[test]
    fn ranges_are_padded_and_narrow_log_ranges_span_decades() {
        assert_eq!(range([3.0, 3.0].into_iter(), Scale::Linear), 2.7..3.3);
        assert_eq!(range([0.0].into_iter(), Scale::Linear), -1.0..1.0);
        let near = |r: Range<f64>, a: f64, b: f64| (r.start / a - 1.0).abs() < 0.01 && (r.end / b - 1.0).abs() < 0.01;
        assert!(near(range([4.0].into_iter(), Scale::Log), 1.0, 10.0));
        assert!(near(range([0.2, 0.5].into_iter(), Scale::Log), 0.1, 1.0));
        let wide = range([1e-3, 1e3].into_iter(), Scale::Log);
        assert!(
            wide.start < 1e-3 && wide.start > 0.5e-3 && wide.end > 1e3 && wide.end < 2e3,
            "{wide:?}"
        );
    }
}
