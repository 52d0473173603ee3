//! The plots a photogrammetrist expects from a calibration: radial residuals against the
//! radius, residual vectors over the image, the camera network in 3D, and maps over the image
//! (projection uncertainty, cross-validation difference). Each is drawn into an SVG string and
//! written atomically.

use std::path::Path;

use nalgebra::{Point3, Vector2, Vector3};
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

use super::ReportError;
use crate::geometry::bounds;
use crate::io::atomic::write_bytes_atomic;

fn draw_err<E: std::fmt::Display>(what: &'static str) -> impl Fn(E) -> ReportError {
    move |e| ReportError::Draw {
        what,
        message: e.to_string(),
    }
}

fn finish(path: &Path, svg: &str) -> Result<(), ReportError> {
    write_bytes_atomic(path, svg.as_bytes())?;
    Ok(())
}

/// Radial residuals `v_r` against the radius `r` (px): a scatter per model, each with its binned
/// mean as a line (a good model shows a flat mean at zero).
///
/// # Errors
/// [`ReportError`] when drawing or writing fails.
pub fn radial_residuals(path: &Path, series: &[(&str, &[(f64, f64)])]) -> Result<(), ReportError> {
    let what = "the radial residual plot";
    let r_max = series
        .iter()
        .flat_map(|(_, s)| s.iter().map(|p| p.0))
        .fold(1.0, f64::max);
    let v_max = series
        .iter()
        .flat_map(|(_, s)| s.iter().map(|p| p.1.abs()))
        .fold(1e-3, f64::max);
    let mut svg = String::new();
    {
        let root =
            SVGBackend::with_string(&mut svg, (900, 300 * series.len() as u32)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err(what))?;
        let areas = root.split_evenly((series.len(), 1));
        for ((name, samples), area) in series.iter().zip(&areas) {
            let v_lim = samples
                .iter()
                .map(|p| p.1.abs())
                .fold(1e-3, f64::max)
                .min(v_max);
            let mut chart = ChartBuilder::on(area)
                .caption(format!("radial residuals: {name}"), ("sans-serif", 16))
                .margin(8)
                .x_label_area_size(30)
                .y_label_area_size(60)
                .build_cartesian_2d(0.0..r_max * 1.02, -v_lim * 1.05..v_lim * 1.05)
                .map_err(draw_err(what))?;
            chart
                .configure_mesh()
                .x_desc("radius r (px)")
                .y_desc("v_r (px)")
                .draw()
                .map_err(draw_err(what))?;
            chart
                .draw_series(
                    samples
                        .iter()
                        .map(|&(r, v)| Circle::new((r, v), 1, BLUE.mix(0.35).filled())),
                )
                .map_err(draw_err(what))?;
            let bins = binned_mean(samples, r_max, 24);
            chart
                .draw_series(LineSeries::new(bins, RED.stroke_width(2)))
                .map_err(draw_err(what))?;
        }
        root.present().map_err(draw_err(what))?;
    }
    finish(path, &svg)
}

/// Mean of `v` in `n` equal bins of `r` over `[0, r_max]` (empty bins left out).
#[must_use]
pub fn binned_mean(samples: &[(f64, f64)], r_max: f64, n: usize) -> Vec<(f64, f64)> {
    let mut sums = vec![(0.0, 0usize); n];
    for &(r, v) in samples {
        let k = ((r / r_max) * n as f64).floor().clamp(0.0, (n - 1) as f64) as usize;
        sums[k].0 += v;
        sums[k].1 += 1;
    }
    sums.iter()
        .enumerate()
        .filter(|(_, (_, c))| *c > 0)
        .map(|(k, (s, c))| ((k as f64 + 0.5) * r_max / n as f64, s / *c as f64))
        .collect()
}

/// Residual vectors over the image, magnified by `scale` (drawn as arrows from each
/// observation).
///
/// # Errors
/// [`ReportError`] when drawing or writing fails.
pub fn residual_vectors(
    path: &Path,
    size: (u32, u32),
    residuals: &[(Vector2<f64>, Vector2<f64>)],
    scale: f64,
) -> Result<(), ReportError> {
    let what = "the residual vector plot";
    let caption = format!("image residuals (×{scale:.0})");
    draw_over_image(path, size, &caption, what, |chart| {
        chart.draw_series(residuals.iter().map(|(uv, r)| {
            PathElement::new(
                vec![(uv.x, uv.y), (uv.x + scale * r.x, uv.y + scale * r.y)],
                BLUE.stroke_width(1),
            )
        }))?;
        chart.draw_series(
            residuals
                .iter()
                .map(|(uv, _)| Circle::new((uv.x, uv.y), 1, BLACK.filled())),
        )?;
        Ok(())
    })
}

/// A chart spanning the image (u right, v down, pixels), drawn by `draw` into an SVG
/// written atomically to `path`.
fn draw_over_image(
    path: &Path,
    size: (u32, u32),
    caption: &str,
    what: &'static str,
    draw: impl FnOnce(&mut ImageChart<'_, '_>) -> Result<(), DrawingAreaErrorKind<std::io::Error>>,
) -> Result<(), ReportError> {
    let (w, h) = (f64::from(size.0), f64::from(size.1));
    let mut svg = String::new();
    {
        let px = 1000;
        let root = SVGBackend::with_string(&mut svg, (px, (f64::from(px) * h / w) as u32 + 60))
            .into_drawing_area();
        root.fill(&WHITE).map_err(draw_err(what))?;
        let mut chart = ChartBuilder::on(&root)
            .caption(caption, ("sans-serif", 16))
            .margin(8)
            .x_label_area_size(25)
            .y_label_area_size(45)
            .build_cartesian_2d(0.0..w, h..0.0)
            .map_err(draw_err(what))?;
        chart.configure_mesh().draw().map_err(draw_err(what))?;
        draw(&mut chart).map_err(draw_err(what))?;
        root.present().map_err(draw_err(what))?;
    }
    finish(path, &svg)
}

/// The chart [`draw_over_image`] hands to its drawing closure.
type ImageChart<'a, 'b> =
    ChartContext<'a, SVGBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// The camera network: projection centres with their viewing directions, and the targets.
///
/// # Errors
/// [`ReportError`] when drawing or writing fails.
pub fn camera_network(
    path: &Path,
    centres: &[Point3<f64>],
    directions: &[Vector3<f64>],
    targets: &[Vector3<f64>],
) -> Result<(), ReportError> {
    let what = "the camera network plot";
    let all: Vec<Vector3<f64>> = centres
        .iter()
        .map(|c| c.coords)
        .chain(targets.iter().copied())
        .collect();
    let (lo, hi) = bounds(all.iter().copied());
    let span = (hi - lo).amax().max(1e-9);
    let arrow = 0.08 * span;
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (900, 800)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err(what))?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                "camera network (blue: cameras and viewing directions, red: targets)",
                ("sans-serif", 16),
            )
            .margin(10)
            .build_cartesian_3d(lo.x..lo.x + span, lo.y..lo.y + span, lo.z..lo.z + span)
            .map_err(draw_err(what))?;
        chart.with_projection(|mut p| {
            p.pitch = 0.5;
            p.yaw = 0.7;
            p.scale = 0.8;
            p.into_matrix()
        });
        chart.configure_axes().draw().map_err(draw_err(what))?;
        chart
            .draw_series(
                targets
                    .iter()
                    .map(|t| Circle::new((t.x, t.y, t.z), 2, RED.filled())),
            )
            .map_err(draw_err(what))?;
        chart
            .draw_series(centres.iter().zip(directions).map(|(c, d)| {
                let e = c.coords + arrow * d;
                PathElement::new(vec![(c.x, c.y, c.z), (e.x, e.y, e.z)], BLUE.stroke_width(1))
            }))
            .map_err(draw_err(what))?;
        chart
            .draw_series(
                centres
                    .iter()
                    .map(|c| Circle::new((c.x, c.y, c.z), 3, BLUE.filled())),
            )
            .map_err(draw_err(what))?;
        root.present().map_err(draw_err(what))?;
    }
    finish(path, &svg)
}

/// A scalar map over the image (`values[j][i]` at cell column i, row j of a regular grid),
/// coloured from white (0) to dark red (the largest value), with the scale in the caption.
///
/// # Errors
/// [`ReportError`] when drawing or writing fails.
pub fn image_map(
    path: &Path,
    size: (u32, u32),
    values: &[Vec<f64>],
    title: &str,
    unit: &str,
) -> Result<(), ReportError> {
    let what = "an image map";
    let (w, h) = (f64::from(size.0), f64::from(size.1));
    let rows = values.len().max(1);
    let cols = values.first().map_or(1, Vec::len).max(1);
    let vmax = values
        .iter()
        .flatten()
        .copied()
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max);
    let caption = format!("{title} (white 0 → dark red {vmax:.4} {unit})");
    let (cw, ch) = (w / cols as f64, h / rows as f64);
    draw_over_image(path, size, &caption, what, |chart| {
        chart.draw_series(values.iter().enumerate().flat_map(|(j, row)| {
            row.iter().enumerate().map(move |(i, v)| {
                let t = if vmax > 0.0 && v.is_finite() {
                    (v / vmax).clamp(0.0, 1.0)
                } else {
                    0.0
                };
                let colour = RGBColor(
                    (255.0 - 115.0 * t) as u8,
                    (255.0 * (1.0 - t)) as u8,
                    (255.0 * (1.0 - t)) as u8,
                );
                Rectangle::new(
                    [
                        (i as f64 * cw, j as f64 * ch),
                        ((i + 1) as f64 * cw, (j + 1) as f64 * ch),
                    ],
                    colour.filled(),
                )
            })
        }))?;
        Ok(())
    })
}

/// Line series with markers against a shared x axis, with a legend in the headroom above the
/// data; `log_y` draws the y axis logarithmically (values ≤ 0 are left out there). For the
/// experiments' figures.
///
/// # Errors
/// [`ReportError`] when drawing or writing fails.
pub fn line_chart(
    path: &Path,
    title: &str,
    axes: (&str, &str),
    series: &[(&str, Vec<(f64, f64)>)],
    log_y: bool,
) -> Result<(), ReportError> {
    let what = "the line chart";
    let points = || {
        series
            .iter()
            .flat_map(|(_, s)| s.iter())
            .filter(|p| p.0.is_finite() && p.1.is_finite() && (!log_y || p.1 > 0.0))
    };
    let (x_lo, x_hi) = points().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
        (lo.min(p.0), hi.max(p.0))
    });
    let (y_lo, y_hi) = points().fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), p| {
        (lo.min(p.1), hi.max(p.1))
    });
    if !(x_lo.is_finite() && y_lo.is_finite()) {
        return Err(ReportError::Draw {
            what,
            message: format!("{title}: no finite points to draw"),
        });
    }
    let x_pad = 0.03 * (x_hi - x_lo).max(1.0);
    let x_range = x_lo - x_pad..x_hi + x_pad;
    let colours = [BLUE, RED, GREEN, MAGENTA, CYAN, BLACK];
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (900, 560)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err(what))?;
        let mut builder = ChartBuilder::on(&root);
        builder
            .caption(title, ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70);
        // Two coordinate types; the drawing below is the same for both.
        macro_rules! draw {
            ($chart:expr, $keep:expr) => {{
                let mut chart = $chart;
                chart
                    .configure_mesh()
                    .x_desc(axes.0)
                    .y_desc(axes.1)
                    .draw()
                    .map_err(draw_err(what))?;
                for (k, (name, s)) in series.iter().enumerate() {
                    let colour = colours[k % colours.len()];
                    let kept: Vec<(f64, f64)> = s.iter().copied().filter($keep).collect();
                    chart
                        .draw_series(LineSeries::new(kept.clone(), colour.stroke_width(2)))
                        .map_err(draw_err(what))?
                        .label(*name)
                        .legend(move |(x, y)| {
                            PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
                        });
                    chart
                        .draw_series(kept.iter().map(|&p| Circle::new(p, 3, colour.filled())))
                        .map_err(draw_err(what))?;
                }
                chart
                    .configure_series_labels()
                    .background_style(WHITE.mix(0.85))
                    .border_style(BLACK)
                    .position(SeriesLabelPosition::UpperRight)
                    .draw()
                    .map_err(draw_err(what))?;
            }};
        }
        if log_y {
            let chart = builder
                .build_cartesian_2d(x_range, (y_lo / 1.5..y_hi * 6.0).log_scale())
                .map_err(draw_err(what))?;
            draw!(chart, |p: &(f64, f64)| p.1 > 0.0 && p.1.is_finite());
        } else {
            let y_pad = 0.05 * (y_hi - y_lo).max(1e-9);
            let chart = builder
                .build_cartesian_2d(x_range, (y_lo.min(0.0) - y_pad)..y_hi + 8.0 * y_pad)
                .map_err(draw_err(what))?;
            draw!(chart, |p: &(f64, f64)| p.1.is_finite());
        }
        root.present().map_err(draw_err(what))?;
    }
    finish(path, &svg)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn binned_mean_averages_each_bin() {
        let s = [(0.1, 1.0), (0.2, 3.0), (0.9, -2.0)];
        let b = binned_mean(&s, 1.0, 2);
        assert_eq!(b, vec![(0.25, 2.0), (0.75, -2.0)]);
    }

    #[test]
    fn plots_are_written_as_svg() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("radial.svg");
        radial_residuals(&p, &[("a", &[(1.0, 0.1), (500.0, -0.2)])]).unwrap();
        let text = std::fs::read_to_string(&p).unwrap();
        assert!(text.starts_with("<svg") && text.contains("radial residuals: a"));
        let m = dir.path().join("map.svg");
        image_map(&m, (100, 50), &[vec![0.0, 1.0], vec![2.0, 3.0]], "σ", "px").unwrap();
        assert!(std::fs::read_to_string(&m).unwrap().contains("<rect"));
    }
    #[test]
    fn line_chart_draws_each_series_and_refuses_an_empty_one() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("chart.svg");
        let a = vec![(1.0, 0.01), (2.0, 1.0), (3.0, 0.0)];
        let b = vec![(1.0, 5.0), (2.0, 4.0)];
        line_chart(&path, "t", ("x", "y"), &[("first", a), ("second", b)], true).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        assert!(svg.contains("first") && svg.contains("second"));
        // On a log axis the zero is left out: 2 + 2 markers drawn.
        assert_eq!(svg.matches("<circle").count(), 4);
        let empty = vec![(1.0, f64::NAN)];
        assert!(line_chart(&path, "t", ("x", "y"), &[("nan", empty)], false).is_err());
    }
}
