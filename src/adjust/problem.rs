//! What is adjusted: poses `cam_from_world`, per-camera and shared intrinsics, 3D points and
//! their image observations, with the parameters held fixed (COLMAP's
//! `BundleAdjustmentConfig`).

use nalgebra::{Vector2, Vector3};

use super::AdjustError;
use super::model::CameraModel;
use crate::camera::rolling::{Motion, MotionOrder};
use crate::geometry::pose::Rigid3;

/// Most per-camera values a model may carry (a fourth-order rolling-shutter motion's 24):
/// the linearisation's stack buffers are this long; [`Problem::validate`]
/// refuses a model with more.
pub(crate) const MAX_LOCAL: usize = crate::camera::rolling::MAX_VALUES;

/// One image measurement of a point.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Observation {
    /// Index of the camera (frame) that saw it.
    pub camera: usize,
    /// Index of the point.
    pub point: usize,
    /// Measured pixel.
    pub uv: Vector2<f64>,
    /// Weight of both coordinates (1/σ² relative to the unit weight); 0 drops it.
    pub weight: f64,
    /// Time of the observation's frame from its camera's frame time (s): 0, or `±1/fps` for
    /// a neighbouring video frame measured with the camera's motion (rolling-shutter models;
    /// others ignore it).
    pub time_offset_s: f64,
}

impl Observation {
    /// A measurement of `point` by `camera` at `uv` with unit weight, in the camera's own
    /// frame.
    #[must_use]
    pub fn new(camera: usize, point: usize, uv: Vector2<f64>) -> Self {
        Observation {
            camera,
            point,
            uv,
            weight: 1.0,
            time_offset_s: 0.0,
        }
    }
}

/// Parameters held at their current value.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct FixedParameters {
    /// Indices of shared intrinsics held fixed.
    pub global: Vec<usize>,
    /// Indices (within one camera's block) of per-camera intrinsics held fixed for every camera.
    pub local: Vec<usize>,
    /// Cameras whose pose is held fixed (empty for a free network).
    pub poses: Vec<usize>,
    /// `(camera, index within its block)` of per-camera intrinsics held fixed for that camera
    /// only (the higher-order motion of a frame without neighbouring video frames on both
    /// sides).
    pub camera_local: Vec<(usize, usize)>,
}

impl FixedParameters {
    /// Indices (within its block) of camera `c`'s per-camera values held fixed: those held
    /// for every camera, then its own (not deduplicated).
    pub(crate) fn local_of(&self, c: usize) -> impl Iterator<Item = usize> + '_ {
        self.local.iter().copied().chain(
            self.camera_local
                .iter()
                .filter(move |(camera, _)| *camera == c)
                .map(|&(_, k)| k),
        )
    }
}

/// A bundle adjustment problem over a camera model `M`.
#[derive(Clone, Debug)]
pub struct Problem<M: CameraModel> {
    /// The projection model.
    pub model: M,
    /// One pose per camera.
    pub cam_from_world: Vec<Rigid3>,
    /// Per-camera intrinsics, `model.local_len()` per camera, camera-major.
    pub local: Vec<f64>,
    /// Shared intrinsics, `model.global_len()` of them.
    pub global: Vec<f64>,
    /// Object points.
    pub points: Vec<Vector3<f64>>,
    /// Image observations.
    pub observations: Vec<Observation>,
    /// What is held fixed.
    pub fixed: FixedParameters,
}

impl<M: CameraModel> Problem<M> {
    /// Builds a problem, checking that every index and length agrees.
    ///
    /// # Errors
    /// [`AdjustError::Invalid`] naming the first inconsistency.
    pub fn new(
        model: M,
        cam_from_world: Vec<Rigid3>,
        local: Vec<f64>,
        global: Vec<f64>,
        points: Vec<Vector3<f64>>,
        observations: Vec<Observation>,
    ) -> Result<Self, AdjustError> {
        let problem = Problem {
            model,
            cam_from_world,
            local,
            global,
            points,
            observations,
            fixed: FixedParameters::default(),
        };
        problem.validate()?;
        Ok(problem)
    }

    /// Checks indices, lengths and finiteness.
    ///
    /// # Errors
    /// [`AdjustError::Invalid`] naming the first inconsistency.
    pub fn validate(&self) -> Result<(), AdjustError> {
        let n_cam = self.cam_from_world.len();
        let invalid = |m: String| Err(AdjustError::Invalid(m));
        if self.model.local_len() > MAX_LOCAL {
            return invalid(format!(
                "the model has {} per-camera values, at most {} are supported",
                self.model.local_len(),
                MAX_LOCAL
            ));
        }
        if self.local.len() != n_cam * self.model.local_len() {
            return invalid(format!(
                "{} per-camera intrinsics for {n_cam} cameras of {} each",
                self.local.len(),
                self.model.local_len()
            ));
        }
        if self.global.len() != self.model.global_len() {
            return invalid(format!(
                "{} shared intrinsics, the model has {}",
                self.global.len(),
                self.model.global_len()
            ));
        }
        if self.observations.is_empty() {
            return Err(AdjustError::NoObservations);
        }
        for (k, o) in self.observations.iter().enumerate() {
            if o.camera >= n_cam || o.point >= self.points.len() {
                return invalid(format!(
                    "observation {k} refers to camera {} / point {} ({n_cam} cameras, {} points)",
                    o.camera,
                    o.point,
                    self.points.len()
                ));
            }
            if !(o.uv.iter().all(|v| v.is_finite())
                && o.weight.is_finite()
                && o.weight >= 0.0
                && o.time_offset_s.is_finite())
            {
                return invalid(format!(
                    "observation {k} is not finite or has a negative weight"
                ));
            }
        }
        if !self
            .points
            .iter()
            .flat_map(|p| p.iter())
            .chain(self.local.iter())
            .chain(self.global.iter())
            .all(|v| v.is_finite())
        {
            return invalid("a point or an intrinsic is not finite".into());
        }
        let fixed_ok = self.fixed.global.iter().all(|&k| k < self.global.len())
            && self.fixed.local.iter().all(|&k| k < self.model.local_len())
            && self
                .fixed
                .camera_local
                .iter()
                .all(|&(c, k)| c < n_cam && k < self.model.local_len())
            && self.fixed.poses.iter().all(|&k| k < n_cam);
        if !fixed_ok {
            return invalid("a fixed-parameter index is out of range".into());
        }
        Ok(())
    }

    /// Number of cameras.
    #[must_use]
    pub fn num_cameras(&self) -> usize {
        self.cam_from_world.len()
    }

    /// One camera's per-camera intrinsics.
    #[must_use]
    pub fn local_of(&self, camera: usize) -> &[f64] {
        let n = self.model.local_len();
        &self.local[camera * n..(camera + 1) * n]
    }

    /// The residual `projected − measured` of one observation (unweighted), `None` where the
    /// model is undefined.
    #[must_use]
    pub fn residual(&self, o: &Observation) -> Option<Vector2<f64>> {
        let p_cam = self.cam_from_world[o.camera] * nalgebra::Point3::from(self.points[o.point]);
        self.model
            .project(
                self.local_of(o.camera),
                &self.global,
                &p_cam.coords,
                o.time_offset_s,
                None,
            )
            .map(|uv| uv - o.uv)
    }

    /// Number of free parameters (poses, per-camera and shared intrinsics, points).
    #[must_use]
    pub fn num_free_parameters(&self) -> usize {
        let n_cam = self.num_cameras();
        let mut fixed_poses = self.fixed.poses.clone();
        fixed_poses.sort_unstable();
        fixed_poses.dedup();
        let fixed_local: usize = (0..n_cam)
            .map(|c| {
                let mut fl: Vec<usize> = self.fixed.local_of(c).collect();
                fl.sort_unstable();
                fl.dedup();
                fl.len()
            })
            .sum();
        let mut fg = self.fixed.global.clone();
        fg.sort_unstable();
        fg.dedup();
        6 * (n_cam - fixed_poses.len())
            + (n_cam * self.model.local_len() - fixed_local)
            + (self.global.len() - fg.len())
            + 3 * self.points.len()
    }
}

impl Problem<super::BrownModel> {
    /// Each camera's motion, read from its block of per-camera values (of whatever motion
    /// order; empty for a global shutter).
    #[must_use]
    pub fn motions(&self) -> Vec<Motion> {
        let len = self.model.local_len();
        if len == 0 {
            return Vec::new();
        }
        self.local.chunks(len).map(Motion::from_slice).collect()
    }

    /// The same problem with a rolling shutter on frames `height_px` rows high: every camera's
    /// motion `(ω, ν)` appended at zero (its per-camera values) and the readout time
    /// `readout_s` as the eleventh shared value; fixed parameters carried over, the motion and
    /// the readout time free. Already rolling: only the height and readout time are set.
    #[must_use]
    pub fn with_rolling_shutter(&self, height_px: f64, readout_s: f64) -> Self {
        let mut p = self.clone();
        p.model = super::BrownModel::rolling_shutter(height_px);
        if self.model.rolling_shutter.is_none() {
            p.local = vec![0.0; 6 * self.num_cameras()];
            p.global.truncate(10);
            p.global.push(readout_s);
            p.fixed.local.clear();
            p.fixed.camera_local.clear();
        } else {
            p.global[super::BrownModel::READOUT] = readout_s;
        }
        p
    }

    /// The same problem with a global shutter: the motions and the readout time dropped (and
    /// any fixed-parameter index of them).
    #[must_use]
    pub fn without_rolling_shutter(&self) -> Self {
        let mut p = self.clone();
        p.model = super::BrownModel::GLOBAL_SHUTTER;
        p.local.clear();
        p.global.truncate(10);
        p.fixed.local.clear();
        p.fixed.camera_local.clear();
        p.fixed.global.retain(|&k| k < 10);
        p
    }

    /// The same rolling-shutter problem with motions of `order`: each camera's higher-order
    /// values appended at zero after those of its present order, and held fixed for the
    /// cameras not in `free` (a frame's accelerations and jerks show only in neighbouring
    /// video frames on both sides of it). A global shutter, or a problem already of that order
    /// or a higher one: unchanged.
    #[must_use]
    pub fn with_motion_order(&self, order: MotionOrder, free: &[bool]) -> Self {
        let present = self.model.motion_order.values();
        let Some(super::model::RowHeight(height_px)) = self.model.rolling_shutter else {
            return self.clone();
        };
        if order.values() <= present {
            return self.clone();
        }
        let mut p = self.clone();
        p.model = super::BrownModel::rolling_shutter_of_order(height_px, order);
        let extra = order.values() - present;
        p.local = self
            .local
            .chunks(present)
            .flat_map(|m| m.iter().copied().chain(std::iter::repeat_n(0.0, extra)))
            .collect();
        for c in 0..self.num_cameras() {
            if !free.get(c).copied().unwrap_or(false) {
                p.fixed
                    .camera_local
                    .extend((present..order.values()).map(|k| (c, k)));
            }
        }
        p
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::adjust::BrownModel;

    /// Two rolling-shutter cameras with first-order motions, three points.
    fn two_moving_cameras() -> Problem<BrownModel> {
        let intrinsics = [
            1500.0, 960.0, 540.0, 0.01, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.02,
        ];
        let points = vec![
            Vector3::new(0.0, 0.0, 2.0),
            Vector3::new(0.3, -0.2, 2.5),
            Vector3::new(-0.4, 0.1, 3.0),
        ];
        let observations = (0..2)
            .flat_map(|c| (0..3).map(move |p| Observation::new(c, p, Vector2::new(960.0, 540.0))))
            .collect();
        Problem::new(
            BrownModel::rolling_shutter(1080.0),
            vec![Rigid3::identity(); 2],
            vec![
                0.1, -0.2, 0.3, 0.01, 0.02, 0.03, 0.4, -0.5, 0.6, 0.04, 0.05, 0.06,
            ],
            intrinsics.to_vec(),
            points,
            observations,
        )
        .unwrap()
    }

    /// A third-order motion keeps each camera's first-order values, starts its accelerations
    /// and jerks at zero, and holds them for the camera not free: 12 fewer unknowns for it.
    #[test]
    fn higher_order_motions_are_appended_at_zero_and_held_where_not_free() {
        let first = two_moving_cameras();
        let third = first.with_motion_order(MotionOrder::Third, &[true, false]);
        third.validate().unwrap();
        assert_eq!(third.model.motion_order, MotionOrder::Third);
        assert_eq!(third.local_of(0)[..6], first.local_of(0)[..]);
        assert_eq!(third.local_of(1)[..6], first.local_of(1)[..]);
        assert!(
            third.local_of(0)[6..]
                .iter()
                .chain(&third.local_of(1)[6..])
                .all(|&v| v == 0.0)
        );
        let held: Vec<usize> = third.fixed.local_of(1).collect();
        assert_eq!(held, (6..18).collect::<Vec<_>>());
        assert_eq!(third.fixed.local_of(0).count(), 0);
        assert_eq!(
            third.num_free_parameters(),
            first.num_free_parameters() + 2 * 12 - 12
        );
        // A lower order, or a global shutter, leaves the problem as it is.
        assert_eq!(
            third
                .with_motion_order(MotionOrder::Second, &[true, true])
                .local,
            third.local
        );
        // From the third order to the fourth: the third's values kept, the snaps appended at
        // zero and held for the camera not free, after its held accelerations and jerks.
        let mut adjusted = third.clone();
        for (k, v) in adjusted.local.iter_mut().enumerate() {
            *v = 0.01 * (k as f64 + 1.0);
        }
        let fourth = adjusted.with_motion_order(MotionOrder::Fourth, &[true, false]);
        fourth.validate().unwrap();
        assert_eq!(fourth.model.motion_order, MotionOrder::Fourth);
        for c in 0..2 {
            assert_eq!(fourth.local_of(c)[..18], adjusted.local_of(c)[..]);
            assert!(fourth.local_of(c)[18..].iter().all(|&v| v == 0.0));
        }
        let held: Vec<usize> = fourth.fixed.local_of(1).collect();
        assert_eq!(held, (6..24).collect::<Vec<_>>());
        assert_eq!(
            fourth.num_free_parameters(),
            third.num_free_parameters() + 6
        );
        let still = first.without_rolling_shutter();
        assert_eq!(
            still
                .with_motion_order(MotionOrder::Third, &[true, true])
                .local,
            still.local
        );
    }
}
