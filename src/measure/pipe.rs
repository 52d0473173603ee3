//! Measuring the pipe (paper, "Evaluation of Impact of Calibration on Pipe Reconstruction"): the
//! dense cloud brought to metres (and into the TLS frame when the targets give a similarity),
//! the pipe of interest taken from the pipe network found there (every pipe once,
//! walls and boxes refused), its radius σ combining the fit's and the scale's, and with a TLS
//! scan the same pipe fitted there as the reference.

use nalgebra::Vector3;

pub use super::choice::Region;
use super::choice::{Choice, View, pipe_of_interest};
use super::cloud::Cloud;
use super::cylinder::{Cylinder, CylinderConfig, CylinderError, CylinderFit, fit_cylinder_among};
use super::network::{Network, NetworkConfig, NetworkError, PipeSegment, extract_network};
use super::scale::ScaleEstimate;
use crate::adjust::Similarity;

/// How the cloud gets its metric scale.
#[derive(Clone, Debug, PartialEq)]
pub enum Scaling {
    /// A scale given by the user (`--scale`; 1 for an already metric cloud).
    Given(f64),
    /// From the targets against the TLS list.
    Targets(ScaleEstimate),
}

impl Scaling {
    /// The scale and its standard deviation.
    #[must_use]
    pub fn scale(&self) -> (f64, f64) {
        match self {
            Scaling::Given(s) => (*s, 0.0),
            Scaling::Targets(e) => e.best(),
        }
    }

    /// The transform applied to the cloud: the similarity into the TLS frame when the targets
    /// give one, else the scale alone (the cloud stays in its own, now metric, frame).
    #[must_use]
    pub fn transform(&self) -> Similarity {
        match self {
            Scaling::Targets(ScaleEstimate {
                similarity: Some(s),
                ..
            }) => s.similarity,
            _ => Similarity {
                scale: self.scale().0,
                ..Similarity::identity()
            },
        }
    }

    /// True when the measured cloud is in the TLS frame (so a TLS scan can be searched where
    /// the pipe was found).
    #[must_use]
    pub fn in_tls_frame(&self) -> bool {
        matches!(
            self,
            Scaling::Targets(ScaleEstimate {
                similarity: Some(_),
                ..
            })
        )
    }
}

/// The measured pipe.
#[derive(Clone, Debug, PartialEq)]
pub struct PipeMeasurement {
    /// The fit in the measured frame (metres).
    pub fit: CylinderFit,
    /// Scale and its σ.
    pub scale: (f64, f64),
    /// Radius σ combining the fit's and the scale's:
    /// `√(σ_fit² + (r·σ_s/s)²)` (the two are independent).
    pub radius_std: f64,
    /// The transform applied to the cloud.
    pub transform: Similarity,
    /// The transformed finite points the fit's inlier indices refer to (the region of interest
    /// applied).
    pub points: Vec<Vector3<f64>>,
    /// The pipe network's segment measured: its axis endpoints, length and nominal size.
    pub segment: PipeSegment,
    /// How many pipe segments the search found, the measured one included.
    pub segments_found: usize,
    /// Every segment the search found (the measured one is `segments[choice.segment]`).
    pub segments: Vec<PipeSegment>,
    /// How the measured segment was chosen.
    pub choice: Choice,
}

/// The reference radius from the TLS scan and the accuracy of the measurement.
#[derive(Clone, Debug, PartialEq)]
pub struct Reference {
    /// The TLS fit.
    pub fit: CylinderFit,
    /// Measured minus reference radius (m).
    pub accuracy: f64,
}

/// Transforms the finite points by `t` and keeps those in `region`.
#[must_use]
pub fn transformed_points(
    points: &[Vector3<f64>],
    t: &Similarity,
    region: Option<&Region>,
) -> Vec<Vector3<f64>> {
    points
        .iter()
        .filter(|p| p.iter().all(|v| v.is_finite()))
        .map(|p| t.apply(p))
        .filter(|p| region.is_none_or(|r| r.contains(p)))
        .collect()
}

/// Scales (and moves) the cloud, then finds every pipe segment and measures the pipe of
/// interest ([`pipe_of_interest`]; `views` are the frames' optical axes in the measured
/// frame, empty when there are none).
///
/// # Errors
///
/// [`CylinderError`]: too few points, bad settings, or no pipe.
pub fn measure_pipe(
    points: &[Vector3<f64>],
    scaling: &Scaling,
    region: Option<&Region>,
    config: &CylinderConfig,
    views: &[View],
) -> Result<PipeMeasurement, CylinderError> {
    let transform = scaling.transform();
    let points = transformed_points(points, &transform, region);
    let network =
        extract_network(&points, &network_config(region, config)).map_err(|e| match e {
            NetworkError::Cloud(e) => CylinderError::Cloud(e),
            NetworkError::Config(e) => e,
        })?;
    let choice = pipe_of_interest(&network.segments, region, config.axis_hint, views)
        .ok_or_else(|| no_pipe(&network))?;
    let segment = network.segments[choice.segment].clone();
    let fit = segment_fit(&segment);
    let scale = scaling.scale();
    let r = fit.cylinder.radius;
    let radius_std = (fit.radius_std.powi(2) + (r * scale.1 / scale.0).powi(2)).sqrt();
    Ok(PipeMeasurement {
        fit,
        scale,
        radius_std,
        transform,
        points,
        segments_found: network.segments.len(),
        segment,
        segments: network.segments,
        choice,
    })
}

/// The network search of the main command: the pipe-network engine's rules with the user's
/// radius range and axis hint; in a region of interest a segment need only be as long as the
/// region's radius (the pipe is cut where the region ends), at most the engine's 0.3 m.
#[must_use]
pub fn network_config(region: Option<&Region>, config: &CylinderConfig) -> NetworkConfig {
    let defaults = NetworkConfig::default();
    NetworkConfig {
        cylinder: config.clone(),
        min_length_m: region.map_or(defaults.min_length_m, |r| {
            defaults.min_length_m.min(r.radius)
        }),
        ..defaults
    }
}

/// The segment as a cylinder fit: its axis through its start, its radius, σ, RMSE and inliers
/// (the engine re-fits each segment alone on its inliers; their RMSE stands for the noise
/// scale).
fn segment_fit(segment: &PipeSegment) -> CylinderFit {
    let (point, direction, _) = segment.axis();
    CylinderFit {
        cylinder: Cylinder {
            point,
            direction,
            radius: segment.radius_m,
        },
        radius_std: segment.radius_std_m,
        rmse: segment.rmse_m,
        inliers: segment.inliers,
        noise_scale: segment.rmse_m,
        inlier_indices: segment.inlier_indices.clone(),
    }
}

/// No pipe of interest: [`CylinderError::NoPipe`] with what the search refused.
fn no_pipe(network: &Network) -> CylinderError {
    CylinderError::NoPipe {
        segments: network.segments.len(),
        refused: network.refused.len(),
    }
}

/// Fits the best cylinder of finite points.
///
/// # Errors
///
/// As [`measure_pipe`].
pub fn fit_points(
    points: &[Vector3<f64>],
    config: &CylinderConfig,
) -> Result<CylinderFit, CylinderError> {
    let cloud = Cloud::new(points)?;
    let all: Vec<usize> = (0..cloud.len()).collect();
    fit_cylinder_among(&cloud, &all, config)
}

/// Fits the same pipe in the TLS scan: when the measurement is in the TLS frame, near the
/// measured axis (within three radii plus 0.2 m of the inliers' middle, axis within 10°);
/// otherwise (two targets: no rotation known) the best cylinder with a radius within 25 % of the
/// measured one.
///
/// # Errors
///
/// As [`measure_pipe`].
pub fn reference_fit(
    scan: &[Vector3<f64>],
    measured: &PipeMeasurement,
    same_frame: bool,
    config: &CylinderConfig,
) -> Result<Reference, CylinderError> {
    reference_fit_among(scan, measured, &measured.points, same_frame, config)
}

/// [`reference_fit`] with the measured points the fit's inliers index given apart.
fn reference_fit_among(
    scan: &[Vector3<f64>],
    measured: &PipeMeasurement,
    measured_points: &[Vector3<f64>],
    same_frame: bool,
    config: &CylinderConfig,
) -> Result<Reference, CylinderError> {
    let c = &measured.fit.cylinder;
    let r = c.radius;
    let mut config = CylinderConfig {
        radius_min: 0.75 * r,
        radius_max: 1.25 * r,
        ..config.clone()
    };
    let region = if same_frame {
        config.axis_hint = Some((c.direction, 10f64.to_radians()));
        // The middle of the inliers, on the axis.
        let n = measured.fit.inlier_indices.len().max(1) as f64;
        let mean = measured
            .fit
            .inlier_indices
            .iter()
            .map(|&i| measured_points[i])
            .sum::<Vector3<f64>>()
            / n;
        let on_axis = c.point + (mean - c.point).dot(&c.direction) * c.direction;
        Some(Region {
            centre: on_axis,
            radius: 3.0 * r + 0.2,
        })
    } else {
        None
    };
    let points = transformed_points(scan, &Similarity::identity(), region.as_ref());
    let fit = fit_points(&points, &config)?;
    Ok(Reference {
        accuracy: r - fit.cylinder.radius,
        fit,
    })
}

/// Fits a segment of the measured cloud in the TLS scan, the scan in the same frame: near its
/// axis (within three radii plus 0.2 m of its inliers' middle, axis within 10°), radius within
/// 25 %. `points` are the measured points its inliers index.
///
/// # Errors
///
/// As [`measure_pipe`].
pub fn segment_reference(
    scan: &[Vector3<f64>],
    segment: &PipeSegment,
    points: &[Vector3<f64>],
    config: &CylinderConfig,
) -> Result<Reference, CylinderError> {
    let fit = segment_fit(segment);
    let measured = PipeMeasurement {
        fit,
        scale: (1.0, 0.0),
        radius_std: segment.radius_std_m,
        transform: Similarity::identity(),
        points: Vec::new(),
        segment: segment.clone(),
        segments_found: 0,
        segments: Vec::new(),
        choice: Choice {
            segment: 0,
            by: super::choice::ChosenBy::Near,
            distance_m: None,
            runner_up: None,
            ambiguous: false,
            alternatives: Vec::new(),
        },
    };
    reference_fit_among(scan, &measured, points, true, config)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A 4-inch run along x (r 57.15 mm, x 0–2 m, 1 m up), a 2-inch riser beside it (r
    /// 30.15 mm, at x 1, y 0.5, z 0.2–1.7 m), a floor and a 0.4 m box; 0.5 mm uniform noise.
    fn room() -> Vec<Vector3<f64>> {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut noise = || (rng.random::<f64>() - 0.5) * 1e-3 * 12f64.sqrt() * 0.5;
        let mut points = Vec::new();
        let mut tube = |r: f64, at: &dyn Fn(f64, f64, f64) -> Vector3<f64>, n: usize| {
            for i in 0..n {
                for k in 0..60 {
                    let a = std::f64::consts::TAU * k as f64 / 60.0;
                    points.push(at((i as f64 + 0.5) / n as f64, a, r + noise()));
                }
            }
        };
        tube(
            0.05715,
            &|t, a, r| Vector3::new(2.0 * t, r * a.cos(), 1.0 + r * a.sin()),
            2000,
        );
        tube(
            0.03015,
            &|t, a, r| Vector3::new(1.0 + r * a.cos(), 0.5 + r * a.sin(), 0.2 + 1.5 * t),
            1000,
        );
        let mut rng = ChaCha8Rng::seed_from_u64(12);
        let mut noise = || (rng.random::<f64>() - 0.5) * 1e-3 * 12f64.sqrt() * 0.5;
        points.extend(crate::measure::network::floor_and_box(&mut noise));
        points
    }

    fn show(g: &PipeSegment) -> String {
        format!("r {} from {:?} to {:?}", g.radius_m, g.start, g.end)
    }

    fn measure(region: Option<Region>, hint: Option<Vector3<f64>>) -> PipeMeasurement {
        let config = CylinderConfig {
            axis_hint: hint.map(|h| (h, 20f64.to_radians())),
            ..NetworkConfig::default().cylinder
        };
        measure_pipe(&room(), &Scaling::Given(1.0), region.as_ref(), &config, &[]).unwrap()
    }

    /// The pipe of interest (the main command on the network engine): near a point,
    /// the pipe whose axis passes nearest it; along a hint, the pipe along it; with neither,
    /// the best-supported pipe. Each at its radius (0.3 mm) with its axis's ends (1 cm);
    /// neither the floor nor the box is a pipe.
    #[test]
    fn the_pipe_of_interest_is_near_the_point_along_the_hint_or_the_best_supported() {
        let riser = |m: &PipeMeasurement| {
            let (a, b) = (Vector3::from(m.segment.start), Vector3::from(m.segment.end));
            assert!(
                (m.fit.cylinder.radius - 0.03015).abs() < 3e-4,
                "{}",
                show(&m.segment)
            );
            let (lo, hi) = if a.z < b.z { (a, b) } else { (b, a) };
            assert!((lo - Vector3::new(1.0, 0.5, 0.2)).norm() < 0.01, "{lo}");
            assert!((hi - Vector3::new(1.0, 0.5, 1.7)).norm() < 0.01, "{hi}");
        };
        let run = measure(None, None);
        assert_eq!(run.segments_found, 2);
        assert!(
            (run.fit.cylinder.radius - 0.05715).abs() < 3e-4,
            "{}",
            show(&run.segment)
        );
        assert!(run.fit.cylinder.direction.x.abs() > 0.999);
        assert_eq!(run.segment.nominal.nps, Some("4"));
        riser(&measure(None, Some(Vector3::z())));
        // Near the riser's middle, 0.5 m from the run's axis: the riser, whole.
        let near = Region {
            centre: Vector3::new(1.0, 0.45, 0.95),
            radius: 0.8,
        };
        let m = measure(Some(near), None);
        assert_eq!(m.segments_found, 2);
        riser(&m);
        assert_eq!(m.segment.nominal.nps, Some("2"));
        // Nothing along y: no pipe, and the error says so.
        let config = CylinderConfig {
            axis_hint: Some((Vector3::y(), 20f64.to_radians())),
            ..NetworkConfig::default().cylinder
        };
        let err = match measure_pipe(&room(), &Scaling::Given(1.0), None, &config, &[]) {
            Ok(m) => panic!("a pipe along y: {}", show(&m.segment)),
            Err(e) => e,
        };
        assert!(
            matches!(err, CylinderError::NoPipe { segments: 0, .. }),
            "{err}"
        );
    }
}
