//! What is adjusted: poses `cam_from_world`, per-camera and shared intrinsics, 3D points and
//! their image observations, with the parameters held fixed (COLMAP's
//! `BundleAdjustmentConfig`).

use nalgebra::{Vector2, Vector3};

use super::AdjustError;
use super::model::CameraModel;
use crate::geometry::pose::Rigid3;

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
        let mut fl = self.fixed.local.clone();
        fl.sort_unstable();
        fl.dedup();
        let mut fg = self.fixed.global.clone();
        fg.sort_unstable();
        fg.dedup();
        6 * (n_cam - fixed_poses.len())
            + n_cam * (self.model.local_len() - fl.len())
            + (self.global.len() - fg.len())
            + 3 * self.points.len()
    }
}

impl Problem<super::BrownModel> {
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
        p.fixed.global.retain(|&k| k < 10);
        p
    }
}
