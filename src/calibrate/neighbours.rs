//! A video frame's neighbours: the frames just before and after it at the video's frame rate
//! (`±1/fps`), which see the same targets a few pixels away. Measured with the frame's
//! rolling-shutter motion at their time offsets ([`crate::camera::rolling`]), they tie the
//! motion to time, so the readout time can be estimated: within one frame only the products
//! readout time × velocity show in the image.
//!
//! [`associate`] pairs each detection of a frame with the same target's detection in a
//! neighbour: over 1/25 s a hand-held camera turns by a fraction of a degree, so the
//! targets move by a few to a few tens of pixels, nearly the same for all of them. The
//! displacement field is found as an affine map of the image, started from the median
//! displacement of mutual nearest detections and refined twice on the pairs it predicts; a
//! pair is kept when the prediction lands within [`GATE_FRACTION`] of the target's own
//! semi-minor axis and the two ellipses have about the same size ([`SIZE_TOLERANCE`]).

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use nalgebra::{Matrix3, Vector2, Vector3};

use crate::detect::{DetectConfig, DetectFilesError, detect_frame_files};
use crate::geometry::conic::Ellipse;
use crate::io::sidecar::{FramesSidecar, NeighbourEntry};
use crate::io::{ReadError, ReadErrorKind};

/// The detected ellipses of a frame's neighbour in the video.
#[derive(Clone, Debug, PartialEq)]
pub struct NeighbourDetections {
    /// Its time from the frame (s).
    pub dt_s: f64,
    /// Its detected ellipses (observed pixels).
    pub ellipses: Vec<Ellipse>,
}

/// A pair is kept when the affine map predicts the neighbour's centre within this fraction of
/// the detection's semi-minor axis: a neighbouring target is at least a diameter away.
pub const GATE_FRACTION: f64 = 0.5;

/// Largest relative difference of the two ellipses' semi-axes of a pair (the scale of a
/// target changes by well under a percent over 1/25 s).
pub const SIZE_TOLERANCE: f64 = 0.15;

/// For each ellipse of `frame`, the index of the same target's ellipse in `neighbour`, if
/// found (every neighbour ellipse used at most once).
#[must_use]
pub fn associate(frame: &[Ellipse], neighbour: &[Ellipse]) -> Vec<Option<usize>> {
    let mut out = vec![None; frame.len()];
    if frame.is_empty() || neighbour.is_empty() {
        return out;
    }
    let nearest = |p: Vector2<f64>, set: &[Ellipse]| -> Option<(usize, f64)> {
        set.iter()
            .enumerate()
            .map(|(k, e)| (k, (e.centre() - p).norm_squared()))
            .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)))
    };
    // Mutual nearest detections: their median displacement starts the map.
    let mut shifts: Vec<Vector2<f64>> = frame
        .iter()
        .enumerate()
        .filter_map(|(i, e)| {
            let (j, _) = nearest(e.centre(), neighbour)?;
            let (back, _) = nearest(neighbour[j].centre(), frame)?;
            (back == i).then(|| neighbour[j].centre() - e.centre())
        })
        .collect();
    if shifts.is_empty() {
        return out;
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let shift = Vector2::new(
        median(&mut shifts.iter().map(|s| s.x).collect()),
        median(&mut shifts.iter().map(|s| s.y).collect()),
    );
    shifts.clear();
    // Affine map [u', v'] = A·[u, v, 1], starting as the translation.
    let mut map = nalgebra::Matrix2x3::new(1.0, 0.0, shift.x, 0.0, 1.0, shift.y);
    for _ in 0..3 {
        out = pairs(frame, neighbour, &map);
        let matched: Vec<(Vector2<f64>, Vector2<f64>)> = out
            .iter()
            .enumerate()
            .filter_map(|(i, j)| Some((frame[i].centre(), neighbour[(*j)?].centre())))
            .collect();
        match fit_affine(&matched) {
            Some(next) => map = next,
            None => break,
        }
    }
    out
}

/// The pairs `map` predicts (nearest first, each neighbour ellipse once).
fn pairs(
    frame: &[Ellipse],
    neighbour: &[Ellipse],
    map: &nalgebra::Matrix2x3<f64>,
) -> Vec<Option<usize>> {
    let mut claims: Vec<(f64, usize, usize)> = Vec::new();
    for (i, e) in frame.iter().enumerate() {
        let c = e.centre();
        let predicted = map * Vector3::new(c.x, c.y, 1.0);
        let gate = GATE_FRACTION * e.b;
        for (j, n) in neighbour.iter().enumerate() {
            let d = (n.centre() - predicted).norm();
            let similar = (n.a / e.a - 1.0).abs() <= SIZE_TOLERANCE
                && (n.b / e.b - 1.0).abs() <= SIZE_TOLERANCE;
            if d <= gate && similar {
                claims.push((d, i, j));
            }
        }
    }
    claims.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
    let mut out = vec![None; frame.len()];
    let mut used = vec![false; neighbour.len()];
    for (_, i, j) in claims {
        if out[i].is_none() && !used[j] {
            out[i] = Some(j);
            used[j] = true;
        }
    }
    out
}

/// Least-squares affine map of the pairs `(from, to)`; `None` for fewer than three or a
/// degenerate set.
fn fit_affine(pairs: &[(Vector2<f64>, Vector2<f64>)]) -> Option<nalgebra::Matrix2x3<f64>> {
    if pairs.len() < 3 {
        return None;
    }
    // Normal equations of [u v 1]·a = u' (and v'), around the centroid for conditioning.
    let n = pairs.len() as f64;
    let mean = pairs.iter().map(|p| p.0).sum::<Vector2<f64>>() / n;
    let mut ata = Matrix3::zeros();
    let mut atb = nalgebra::Matrix3x2::zeros();
    for (from, to) in pairs {
        let x = Vector3::new(from.x - mean.x, from.y - mean.y, 1.0);
        ata += x * x.transpose();
        atb += x * to.transpose();
    }
    let sol = ata.try_inverse()? * atb;
    // Back from centred coordinates: t' = t − M·mean.
    let m = nalgebra::Matrix2::new(sol[(0, 0)], sol[(1, 0)], sol[(0, 1)], sol[(1, 1)]);
    let t = Vector2::new(sol[(2, 0)], sol[(2, 1)]) - m * mean;
    Some(nalgebra::Matrix2x3::new(
        m[(0, 0)],
        m[(0, 1)],
        t.x,
        m[(1, 0)],
        m[(1, 1)],
        t.y,
    ))
}

/// The detections in the model frames' neighbours in the video, as `FRAMES/frames.json`
/// (schema `pipemeasure.frames/1`, written by `calibrate --video` and `simulate --video
/// --neighbours`) lists them: per name of `names` (the model's frames, in its order), each
/// neighbour's time offset and detected ellipses. Empty when there is no sidecar or it lists
/// no neighbour. The neighbours are frames of the same camera, checked against `size` before
/// any is decoded; detection runs in parallel ([`detect_frame_files`]); `start` is told how
/// many neighbour frames there are before the first is decoded, `progress` is called once per
/// neighbour frame done.
///
/// # Errors
///
/// [`DetectFilesError`]: a bad sidecar (naming its field), a listed neighbour that is not in
/// `frames`, or a neighbour frame that cannot be read or is of another size.
pub fn detect_neighbours(
    frames: &Path,
    names: &[String],
    size: (u32, u32),
    config: &DetectConfig,
    start: &dyn Fn(usize),
    progress: &(dyn Fn() + Sync),
) -> Result<Vec<Vec<NeighbourDetections>>, DetectFilesError> {
    let path = frames.join("frames.json");
    if !path.is_file() {
        return Ok(Vec::new());
    }
    let sidecar = FramesSidecar::read(&path)?;
    // Indexed once: a search per model image would be quadratic in a long sidecar.
    let by_name: HashMap<&str, &[NeighbourEntry]> = sidecar
        .frames
        .iter()
        .map(|f| (f.name.as_str(), f.neighbours.as_slice()))
        .collect();
    let lists: Vec<&[NeighbourEntry]> = names
        .iter()
        .map(|n| by_name.get(n.as_str()).copied().unwrap_or_default())
        .collect();
    let paths: Vec<PathBuf> = lists
        .iter()
        .flat_map(|l| l.iter().map(|n| frames.join(&n.name)))
        .collect();
    if paths.is_empty() {
        return Ok(Vec::new());
    }
    if let Some(missing) = paths.iter().find(|p| !p.is_file()) {
        return Err(ReadError::new(
            &path,
            ReadErrorKind::Invalid(format!(
                "neighbour frame {} is not in {}",
                missing.display(),
                frames.display()
            )),
        )
        .into());
    }
    start(paths.len());
    let mut detected = detect_frame_files(&paths, size, config, progress)?.into_iter();
    Ok(lists
        .iter()
        .map(|l| {
            l.iter()
                .zip(detected.by_ref())
                .map(|(n, ellipses)| NeighbourDetections {
                    dt_s: n.dt_s,
                    ellipses,
                })
                .collect()
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    fn grid(rng: &mut rand_chacha::ChaCha8Rng) -> Vec<Ellipse> {
        (0..12)
            .flat_map(|r| (0..20).map(move |c| (r, c)))
            .map(|(r, c)| Ellipse {
                cx: 60.0 + 45.0 * f64::from(c) + rng.random_range(-3.0..3.0),
                cy: 50.0 + 45.0 * f64::from(r) + rng.random_range(-3.0..3.0),
                a: 12.0,
                b: 9.0,
                theta: 0.3,
            })
            .collect()
    }

    /// A frame's targets moved by a rotation of 0.4° about a point off the image and a shift
    /// of 19 px (more than a third of the spacing): every pair found, in order, with two
    /// targets missing in the neighbour and a spurious small blob added.
    #[test]
    fn a_turned_and_shifted_neighbour_is_paired_target_by_target() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let frame = grid(&mut rng);
        let (s, c) = 0.4f64.to_radians().sin_cos();
        let moved = |e: &Ellipse| {
            let (u, v) = (e.cx - 2000.0, e.cy + 300.0);
            Ellipse {
                cx: c * u - s * v + 2000.0 + 17.0 + rng_free_jitter(e.cx),
                cy: s * u + c * v - 300.0 - 8.5,
                ..*e
            }
        };
        let mut neighbour: Vec<Ellipse> = frame.iter().map(moved).collect();
        neighbour.remove(100);
        neighbour.remove(7);
        neighbour.push(Ellipse {
            cx: 300.0,
            cy: 300.0,
            a: 3.0,
            b: 2.5,
            theta: 0.0,
        });
        let pairs = associate(&frame, &neighbour);
        for (i, p) in pairs.iter().enumerate() {
            let expected = match i {
                7 | 100 => None,
                i if i < 7 => Some(i),
                i if i < 101 => Some(i - 1),
                i => Some(i - 2),
            };
            assert_eq!(*p, expected, "detection {i}");
        }
    }

    /// A deterministic sub-pixel jitter of the neighbour's centres (detection noise).
    fn rng_free_jitter(x: f64) -> f64 {
        0.05 * (x * 12.9898).sin()
    }

    #[test]
    fn nothing_to_pair_gives_nothing() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(6);
        let frame = grid(&mut rng);
        assert!(associate(&frame, &[]).iter().all(Option::is_none));
        assert!(associate(&[], &frame).is_empty());
    }
}
