//! Which pipe the user filmed: the pipe of interest among the segments of a site's network.
//!
//! With `--near` it is the segment whose axis passes nearest the point; along `--axis-hint`
//! only the segments along the hint are candidates. Otherwise the frames say it: a site is
//! filmed around the pipe of interest, so it lies at the centre of the frames. Each frame
//! votes for the pipe its optical axis meets first — the nearest segment along the axis whose
//! surface the axis passes within an aim error of ([`AIM_ERROR_FRACTION`] of the distance) —
//! and the segment with the most votes is the pipe of interest. The point the axes converge
//! on would not do: a camera circling a pipe aims at points along it, and the axes then
//! cross 15–20 cm behind it, where a second pipe may run. When another segment has half as
//! many votes or more, the choice is ambiguous and the candidates are named. Without frames,
//! or when too few frames look at any pipe (a walk along a room's walls), the best-supported
//! segment (most inliers) is measured and the output says so.

use nalgebra::Vector3;
use serde::Serialize;

use super::network::PipeSegment;

/// A region of interest: points within `radius` of `centre` (in the measured frame).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Region {
    /// Centre.
    pub centre: Vector3<f64>,
    /// Radius.
    pub radius: f64,
}

impl Region {
    /// Whether `p` lies in the region.
    #[must_use]
    pub fn contains(&self, p: &Vector3<f64>) -> bool {
        (p - self.centre).norm() <= self.radius
    }
}

/// A frame's optical axis in the measured frame: its camera centre and unit viewing
/// direction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct View {
    /// Camera centre (m).
    pub centre: Vector3<f64>,
    /// Unit direction of the optical axis (the camera's +Z).
    pub direction: Vector3<f64>,
}

/// How the pipe of interest was chosen.
#[derive(Clone, Debug, PartialEq, Serialize)]
#[serde(tag = "by", rename_all = "kebab-case")]
pub enum ChosenBy {
    /// The segment whose axis passes nearest the `--near` point.
    Near,
    /// The segment most frames' optical axes meet first.
    Frames {
        /// Its votes.
        votes: usize,
        /// The frames.
        frames: usize,
    },
    /// The segment with the most inliers (among those along the axis hint, when given), for
    /// the reason given.
    MostInliers {
        /// Why the frames did not choose.
        reason: String,
    },
}

/// The pipe of interest and how it was chosen.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Choice {
    /// Index of the chosen segment in the network's list.
    pub segment: usize,
    /// How.
    #[serde(flatten)]
    pub by: ChosenBy,
    /// Distance from the `--near` point to the chosen segment's axis (m).
    pub distance_m: Option<f64>,
    /// The next candidate with its distance (m) from the `--near` point, its votes or its
    /// inliers, when there is one.
    pub runner_up: Option<(usize, f64)>,
    /// Whether another segment is as good a choice (as near within the sum of both radii, half
    /// as many votes or more, or inliers within a tenth): the candidates are then `segment`
    /// and `alternatives`.
    pub ambiguous: bool,
    /// The other candidates as good as the chosen one (indices).
    pub alternatives: Vec<usize>,
}

impl Choice {
    /// The same choice with each segment index `k` renamed `rename(k)` (the site report names
    /// segments by their ids).
    #[must_use]
    pub fn renamed(&self, rename: impl Fn(usize) -> usize) -> Choice {
        Choice {
            segment: rename(self.segment),
            by: self.by.clone(),
            distance_m: self.distance_m,
            runner_up: self.runner_up.map(|(k, d)| (rename(k), d)),
            ambiguous: self.ambiguous,
            alternatives: self.alternatives.iter().map(|&k| rename(k)).collect(),
        }
    }
}

/// A frame's optical axis meets a pipe when it passes within the pipe's radius plus this
/// fraction of the distance from the camera (3°: a hand's aim at the pipe it films).
pub const AIM_ERROR_FRACTION: f64 = 0.05;
/// Fewest votes, and fewest as a fraction of the frames, for the frames to choose.
const MIN_VOTES: usize = 3;
/// See [`MIN_VOTES`].
const MIN_VOTE_FRACTION: f64 = 0.2;
/// Another segment with at least this fraction of the winner's votes is filmed as much.
const AMBIGUITY_VOTES: f64 = 0.5;
/// Another segment whose axis passes within this many times the sum of both radii further
/// from the `--near` point than the nearest is as near: two pipes that touch or meet there (a
/// tee, whose branch's axis ends at the run's surface).
const AMBIGUITY_RADII: f64 = 1.0;
/// Two segments whose inliers differ by less than this fraction are equally well supported.
const INLIER_TIE_FRACTION: f64 = 0.1;

/// Distance from `p` to the segment's axis between its endpoints.
#[must_use]
pub fn axis_distance(segment: &PipeSegment, p: &Vector3<f64>) -> f64 {
    let (a, d, l) = segment.axis();
    let t = (p - a).dot(&d).clamp(0.0, l);
    (p - (a + t * d)).norm()
}

/// The closest approach of the optical axis (a ray from the camera) to the segment's axis
/// between its ends: (distance, depth along the ray); `None` when it lies behind the camera.
fn ray_to_segment(view: &View, segment: &PipeSegment) -> Option<(f64, f64)> {
    let (p, d, l) = segment.axis();
    let (c, a) = (view.centre, view.direction);
    let w = c - p;
    let b = a.dot(&d);
    let denom = 1.0 - b * b;
    // The segment's parameter of the closest approach of the two lines (the middle for
    // parallel ones), clamped to the segment; then the ray's.
    let u = if denom > 1e-12 {
        (d.dot(&w) - b * a.dot(&w)) / denom
    } else {
        0.5 * l
    };
    let q = p + d * u.clamp(0.0, l);
    let t = (q - c).dot(&a);
    (t > 0.0).then(|| ((q - (c + a * t)).norm(), t))
}

/// The segment (one of `candidates`, indices into `segments`) the optical axis `view` meets
/// first: of the segments whose axis it passes within their radius plus the aim error, the
/// one whose surface comes nearest the camera along it.
fn first_met(view: &View, segments: &[PipeSegment], candidates: &[usize]) -> Option<usize> {
    candidates
        .iter()
        .filter_map(|&k| {
            let (d, t) = ray_to_segment(view, &segments[k])?;
            let r = segments[k].radius_m;
            (d <= r + AIM_ERROR_FRACTION * t).then_some((k, t - r))
        })
        .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)))
        .map(|(k, _)| k)
}

/// The pipe of interest among `segments` ([`Choice`]): those within the axis hint's angle
/// (when given); of them the one whose axis passes nearest the region's centre (`--near`),
/// else the one most of the frames' optical axes `views` meet first, else the one with the
/// most inliers. Ties keep the first segment. `None` when no segment qualifies.
#[must_use]
pub fn pipe_of_interest(
    segments: &[PipeSegment],
    region: Option<&Region>,
    axis_hint: Option<(Vector3<f64>, f64)>,
    views: &[View],
) -> Option<Choice> {
    let along_hint = |g: &PipeSegment| {
        axis_hint.is_none_or(|(hint, angle)| {
            let (_, d, _) = g.axis();
            d.dot(&hint).abs() >= angle.cos() - 1e-12
        })
    };
    let candidates: Vec<usize> = (0..segments.len())
        .filter(|&k| along_hint(&segments[k]))
        .collect();
    if candidates.is_empty() {
        return None;
    }
    if let Some(r) = region {
        return Some(nearest(segments, &candidates, &r.centre));
    }
    let reason = if views.is_empty() {
        "no frames to choose by".to_string()
    } else {
        match by_frames(segments, &candidates, views) {
            Ok(choice) => return Some(choice),
            Err(reason) => reason,
        }
    };
    // The best-supported segment: the most inliers; the first of equals.
    let best = candidates
        .iter()
        .copied()
        .rev()
        .max_by_key(|&k| segments[k].inliers)?;
    let n = segments[best].inliers as f64;
    let mut others: Vec<(usize, usize)> = candidates
        .iter()
        .filter(|&&k| k != best)
        .map(|&k| (k, segments[k].inliers))
        .collect();
    others.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    let alternatives: Vec<usize> = others
        .iter()
        .filter(|&&(_, m)| m as f64 >= (1.0 - INLIER_TIE_FRACTION) * n)
        .map(|&(k, _)| k)
        .collect();
    Some(Choice {
        segment: best,
        by: ChosenBy::MostInliers { reason },
        distance_m: None,
        runner_up: others.first().map(|&(k, m)| (k, m as f64)),
        ambiguous: !alternatives.is_empty(),
        alternatives,
    })
}

/// The candidate whose axis passes nearest `point`.
fn nearest(segments: &[PipeSegment], candidates: &[usize], point: &Vector3<f64>) -> Choice {
    let mut ranked: Vec<(usize, f64)> = candidates
        .iter()
        .map(|&k| (k, axis_distance(&segments[k], point)))
        .collect();
    ranked.sort_by(|a, b| a.1.total_cmp(&b.1).then(a.0.cmp(&b.0)));
    let (best, d1) = ranked[0];
    let r1 = segments[best].radius_m;
    let alternatives: Vec<usize> = ranked[1..]
        .iter()
        .filter(|&&(k, d)| d - d1 <= AMBIGUITY_RADII * (r1 + segments[k].radius_m))
        .map(|&(k, _)| k)
        .collect();
    Choice {
        segment: best,
        by: ChosenBy::Near,
        distance_m: Some(d1),
        runner_up: ranked.get(1).copied(),
        ambiguous: !alternatives.is_empty(),
        alternatives,
    }
}

/// The candidate most frames' optical axes meet first, or why the frames cannot say.
fn by_frames(
    segments: &[PipeSegment],
    candidates: &[usize],
    views: &[View],
) -> Result<Choice, String> {
    let mut votes = vec![0usize; segments.len()];
    for v in views {
        if let Some(k) = first_met(v, segments, candidates) {
            votes[k] += 1;
        }
    }
    let mut ranked: Vec<(usize, usize)> = candidates.iter().map(|&k| (k, votes[k])).collect();
    ranked.sort_by(|a, b| {
        b.1.cmp(&a.1)
            .then(segments[b.0].inliers.cmp(&segments[a.0].inliers))
            .then(a.0.cmp(&b.0))
    });
    let (best, n) = ranked[0];
    let needed = MIN_VOTES.max((MIN_VOTE_FRACTION * views.len() as f64).ceil() as usize);
    if n < needed {
        return Err(format!(
            "at most {n} of the {} frames' optical axes meet one pipe, {needed} needed",
            views.len()
        ));
    }
    let alternatives: Vec<usize> = ranked[1..]
        .iter()
        .filter(|&&(_, m)| m > 0 && m as f64 >= AMBIGUITY_VOTES * n as f64)
        .map(|&(k, _)| k)
        .collect();
    Ok(Choice {
        segment: best,
        by: ChosenBy::Frames {
            votes: n,
            frames: views.len(),
        },
        distance_m: None,
        runner_up: ranked.get(1).map(|&(k, m)| (k, m as f64)),
        ambiguous: !alternatives.is_empty(),
        alternatives,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::measure::nominal::{PipeMaterial, nominal_size};

    fn segment(start: [f64; 3], end: [f64; 3], r: f64, inliers: usize) -> PipeSegment {
        PipeSegment {
            id: 0,
            start,
            end,
            length_m: (Vector3::from(end) - Vector3::from(start)).norm(),
            radius_m: r,
            radius_std_m: 0.0,
            rmse_m: 0.0,
            inliers,
            searched_inliers: inliers,
            coverage_deg: 180.0,
            normal_deviation_deg: 0.0,
            normal_turn: 1.0,
            shape_departure_m: 0.0,
            nominal: nominal_size(2e3 * r, PipeMaterial::Steel),
            inlier_indices: Vec::new(),
        }
    }

    /// Cameras on an arc of ±55° about a vertical through `target`, `distance` away and 0.15 m
    /// higher, each aimed at a point of the pipe along x that slides with the camera (`slide`
    /// × sin of its angle; the simulator's site path slides 0.25 m) with `jitter` (m) of aim
    /// error alternating up and down.
    fn arc(target: Vector3<f64>, n: usize, slide: f64, jitter: f64) -> Vec<View> {
        let distance = 1.6;
        (0..n)
            .map(|k| {
                let theta = (-55.0 + 110.0 * k as f64 / (n - 1) as f64).to_radians();
                let centre =
                    target + Vector3::new(distance * theta.sin(), distance * theta.cos(), 0.15);
                let up = if k % 2 == 0 { jitter } else { -jitter };
                let aim = target + Vector3::new(slide * theta.sin(), 0.0, up);
                View {
                    centre,
                    direction: (aim - centre).normalize(),
                }
            })
            .collect()
    }

    /// Two horizontal pipes along x: a 2-inch one (r 30 mm) at y 0.52 and a 6-inch one
    /// (r 84 mm, more inliers) 0.14 m further back and 4 cm lower. Frames circling the 2-inch
    /// one at 1.6 m with 4 cm of aim error choose it, every frame's axis meeting it first (the
    /// axes converge 15–20 cm behind it, on the 6-inch one: not the test); with no frames the
    /// 6-inch (most inliers); frames circling the 6-inch where the 2-inch does not hide it
    /// choose it; a row of frames looking at the wall above both meets neither.
    #[test]
    fn the_frames_choose_the_pipe_at_their_centre() {
        let segments = vec![
            segment([-0.9, 0.38, 1.26], [0.7, 0.38, 1.26], 0.084, 170_000),
            segment([-0.53, 0.52, 1.3], [0.63, 0.52, 1.3], 0.030, 53_000),
        ];
        let front = Vector3::new(0.05, 0.52, 1.3);
        let choice = pipe_of_interest(&segments, None, None, &arc(front, 20, 0.25, 0.04)).unwrap();
        assert_eq!(choice.segment, 1, "{choice:?}");
        assert_eq!(
            choice.by,
            ChosenBy::Frames {
                votes: 20,
                frames: 20
            }
        );
        assert!(!choice.ambiguous, "{choice:?}");

        let none = pipe_of_interest(&segments, None, None, &[]).unwrap();
        assert_eq!(none.segment, 0);
        assert!(matches!(none.by, ChosenBy::MostInliers { .. }));

        let back = Vector3::new(-0.8, 0.38, 1.26);
        let choice = pipe_of_interest(&segments, None, None, &arc(back, 20, 0.05, 0.04)).unwrap();
        assert_eq!(choice.segment, 0, "{choice:?}");

        let above: Vec<View> = (0..20)
            .map(|k| View {
                centre: Vector3::new(-1.0 + 0.1 * k as f64, 2.0, 2.2),
                direction: -Vector3::y(),
            })
            .collect();
        let walk = pipe_of_interest(&segments, None, None, &above).unwrap();
        assert!(matches!(walk.by, ChosenBy::MostInliers { .. }), "{walk:?}");
    }

    /// A tee: half the frames aim at the junction, where the branch (r 30 mm, from below) meets
    /// the run (r 57 mm) at its surface, and meet the run first; half aim 25 cm down the branch
    /// and meet it: ambiguous, both named. `--near` the junction: the run, with the branch as
    /// good.
    #[test]
    fn a_tee_filmed_at_its_junction_is_ambiguous() {
        let segments = vec![
            segment([-1.0, 0.5, 1.3], [1.0, 0.5, 1.3], 0.057, 90_000),
            segment([0.0, 0.5, 0.0], [0.0, 0.5, 1.243], 0.030, 40_000),
        ];
        let views: Vec<View> = arc(Vector3::new(0.0, 0.5, 1.3), 20, 0.0, 0.0)
            .into_iter()
            .enumerate()
            .map(|(k, v)| {
                let aim = Vector3::new(0.0, 0.5, if k % 2 == 0 { 1.3 } else { 1.05 });
                View {
                    direction: (aim - v.centre).normalize(),
                    ..v
                }
            })
            .collect();
        let choice = pipe_of_interest(&segments, None, None, &views).unwrap();
        assert!(choice.ambiguous, "{choice:?}");
        let mut named = choice.alternatives.clone();
        named.push(choice.segment);
        named.sort_unstable();
        assert_eq!(named, vec![0, 1]);
        let near = Region {
            centre: Vector3::new(0.0, 0.5, 1.3),
            radius: 0.5,
        };
        let choice = pipe_of_interest(&segments, Some(&near), None, &[]).unwrap();
        assert_eq!(
            (choice.segment, choice.alternatives.as_slice()),
            (0, &[1][..])
        );
    }
}
