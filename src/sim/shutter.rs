//! Rolling-shutter timing: when each sensor row is exposed, the exact rolling-shutter
//! projection of a world point, and a pose table for the renderer.
//!
//! # Row timing (fixed convention)
//!
//! Rows are rows of the *distorted* (observed) image, v ∈ [0, H) with 0 at the top edge. The
//! exposure of the row at pixel height v is centred at
//!
//! ```text
//! t(v) = t_frame + (v/H − 1/2)·readout
//! ```
//!
//! (the middle row at the frame time) and lasts `[t(v) − exposure/2, t(v) + exposure/2]`. v is
//! continuous: a sample at v = 10.25 is exposed around t(10.25).
//!
//! # Exact rolling-shutter projection
//!
//! A world point X is seen in the row v that solves `v = proj_v(X; cam_from_world(t(v)))`
//! (the row that sees it depends on where it is seen). The solver iterates the fixed point
//! once and then secant steps on `g(v) = proj_v(X; t(v)) − v`; the fixed-point map contracts
//! with factor |∂v/∂t|·readout/H (image speed × readout / height, below 0.01 for hand-held
//! video), so it converges in two to four evaluations (Ait-Aider et al., "Simultaneous object
//! pose and velocity computation using a single view from a rolling shutter camera", ECCV
//! 2006, use the same row constraint).

use nalgebra::{Point3, UnitQuaternion, Vector2, Vector3};

use crate::camera::BrownCamera;
use crate::geometry::Rigid3;
use crate::geometry::pose::camera_centre;

/// Timing of one frame of a rolling-shutter camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Shutter {
    /// Frame time: the middle of the exposure of the middle row (s).
    pub time_s: f64,
    /// Readout time: from the top row's exposure to the bottom row's (s); 0 = global shutter.
    pub readout_s: f64,
    /// Exposure time of each row (s); 0 = no motion blur.
    pub exposure_s: f64,
}

impl Shutter {
    /// A global shutter with an instantaneous exposure at `time_s`.
    #[must_use]
    pub fn global(time_s: f64) -> Self {
        Shutter {
            time_s,
            readout_s: 0.0,
            exposure_s: 0.0,
        }
    }

    /// The middle of the exposure of the row at pixel height `v` in an image `height` rows
    /// high.
    #[must_use]
    pub fn row_time(&self, v: f64, height: u32) -> f64 {
        self.time_s + (v / f64::from(height) - 0.5) * self.readout_s
    }

    /// The time span over which some row of the frame is exposed: from the top row's exposure
    /// start to the bottom row's exposure end.
    #[must_use]
    pub fn span(&self) -> (f64, f64) {
        let half = 0.5 * (self.readout_s + self.exposure_s);
        (self.time_s - half, self.time_s + half)
    }
}

/// A world point as a rolling-shutter camera sees it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RollingProjection {
    /// The distorted pixel.
    pub uv: Vector2<f64>,
    /// The time it is seen: the middle of its row's exposure (s).
    pub time_s: f64,
}

/// Largest |g(v)| accepted by [`project_rolling_shutter`] (px).
pub const ROW_TOLERANCE_PX: f64 = 1e-9;
/// Iterations allowed before giving up.
const MAX_ITERATIONS: usize = 40;

/// The exact rolling-shutter projection of `p_world` through `camera` moving as `pose_at(t)`,
/// starting the search at row `v_start` (the frame-time projection when `None`). `None` when
/// the point is behind the camera at a time the search visits or the search does not converge
/// (it always does for hand-held motion; see the module documentation).
#[must_use]
pub fn project_rolling_shutter(
    camera: &BrownCamera,
    shutter: &Shutter,
    pose_at: impl Fn(f64) -> Rigid3,
    p_world: &Vector3<f64>,
    v_start: Option<f64>,
) -> Option<RollingProjection> {
    let h = camera.height;
    let project = |v: f64| {
        let t = shutter.row_time(v, h);
        camera.project_world(&pose_at(t), p_world).map(|uv| (uv, t))
    };
    let mut v = match v_start {
        Some(v) => v,
        None => project(f64::from(h) / 2.0)?.0.y,
    };
    let mut previous: Option<(f64, f64)> = None;
    for _ in 0..MAX_ITERATIONS {
        let (uv, t) = project(v)?;
        let g = uv.y - v;
        if g.abs() <= ROW_TOLERANCE_PX {
            return Some(RollingProjection { uv, time_s: t });
        }
        let next = match previous {
            Some((vp, gp)) if g != gp => v - g * (v - vp) / (g - gp),
            _ => uv.y,
        };
        previous = Some((v, g));
        v = next;
        if !v.is_finite() {
            return None;
        }
    }
    None
}

/// Poses sampled densely over a frame's exposure, interpolated linearly (camera centre) and
/// by normalised linear interpolation (rotation): the renderer's pose source, much cheaper
/// than evaluating the trajectory per sample. With samples 10 µs apart the interpolation error
/// is `step²/8 · |acceleration|`: below 1e-9 rad and 1e-9 m for hand-held motion (measured
/// 6e-10 rad next to a station, where the move toward a pause accelerates at ≈ 50 rad/s²;
/// ≈ 2e-6 px at 4K), far below anything the renderer resolves.
#[derive(Clone, Debug)]
pub struct PoseTable {
    t0: f64,
    step: f64,
    origins: Vec<Point3<f64>>,
    world_from_cam: Vec<UnitQuaternion<f64>>,
}

/// Spacing of [`PoseTable`] samples (s).
pub const POSE_TABLE_STEP_S: f64 = 1e-5;

impl PoseTable {
    /// Samples `pose_at` over `[t0, t1]` (plus one step each side).
    #[must_use]
    pub fn new(pose_at: impl Fn(f64) -> Rigid3, t0: f64, t1: f64) -> Self {
        let step = POSE_TABLE_STEP_S;
        let start = t0 - step;
        let n = ((t1 - t0) / step).ceil() as usize + 3;
        let mut origins = Vec::with_capacity(n);
        let mut world_from_cam: Vec<UnitQuaternion<f64>> = Vec::with_capacity(n);
        for k in 0..n {
            let pose = pose_at(start + k as f64 * step);
            origins.push(camera_centre(&pose));
            let mut q = pose.rotation.inverse();
            // Keep the quaternions on one hemisphere so that neighbours interpolate.
            if let Some(prev) = world_from_cam.last()
                && q.coords.dot(&prev.coords) < 0.0
            {
                q = UnitQuaternion::new_unchecked(-q.into_inner());
            }
            world_from_cam.push(q);
        }
        PoseTable {
            t0: start,
            step,
            origins,
            world_from_cam,
        }
    }

    /// A table for a camera that does not move (one entry, returned exactly).
    #[must_use]
    pub fn fixed(cam_from_world: &Rigid3) -> Self {
        PoseTable {
            t0: 0.0,
            step: 1.0,
            origins: vec![camera_centre(cam_from_world)],
            world_from_cam: vec![cam_from_world.rotation.inverse()],
        }
    }

    /// The camera centre (world) and the rotation `world_from_cam` at time t (clamped to the
    /// table's span).
    #[must_use]
    pub fn at(&self, t: f64) -> (Point3<f64>, UnitQuaternion<f64>) {
        let last = self.origins.len() - 1;
        if last == 0 {
            return (self.origins[0], self.world_from_cam[0]);
        }
        let x = ((t - self.t0) / self.step).clamp(0.0, last as f64);
        let i = (x as usize).min(last - 1);
        let f = x - i as f64;
        let origin = self.origins[i] + (self.origins[i + 1] - self.origins[i]) * f;
        let (qa, qb) = (self.world_from_cam[i], self.world_from_cam[i + 1]);
        let q = qa.into_inner() * (1.0 - f) + qb.into_inner() * f;
        (origin, UnitQuaternion::from_quaternion(q))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Intrinsics;
    use crate::sim::lab::{LabConfig, path};
    use crate::sim::trajectory::{MotionConfig, Trajectory};

    fn p30_like(width: u32, height: u32) -> BrownCamera {
        crate::sim::devices::P30.camera.scaled(width, height)
    }

    fn lab_trajectory(config: &MotionConfig) -> Trajectory {
        let poses: Vec<Rigid3> = path(
            &LabConfig {
                frames: 6,
                ..Default::default()
            },
            2,
        )
        .into_iter()
        .map(|s| s.cam_from_world)
        .collect();
        Trajectory::through(&poses, 1.0, config, 8)
    }

    /// Brute force: every row from −H/2 to 3H/2 in steps of 0.05 px, the sign changes of
    /// g(v) = proj_v(t(v)) − v refined by bisection.
    fn brute_force(
        camera: &BrownCamera,
        shutter: &Shutter,
        tr: &Trajectory,
        p: &Vector3<f64>,
    ) -> Vec<(Vector2<f64>, f64)> {
        let h = camera.height;
        let g = |v: f64| {
            let t = shutter.row_time(v, h);
            camera
                .project_world(&tr.cam_from_world(t), p)
                .map(|uv| (uv.y - v, uv, t))
        };
        let mut roots = Vec::new();
        let n = 40 * h as usize;
        let v_at = |k: usize| -0.5 * f64::from(h) + k as f64 * 0.05;
        for k in 0..n {
            let (a, b) = (v_at(k), v_at(k + 1));
            let (Some((ga, _, _)), Some((gb, _, _))) = (g(a), g(b)) else {
                continue;
            };
            if ga == 0.0 || ga.signum() != gb.signum() {
                let (mut lo, mut hi, mut glo) = (a, b, ga);
                for _ in 0..80 {
                    let mid = 0.5 * (lo + hi);
                    let gm = g(mid).map_or(0.0, |x| x.0);
                    if gm.signum() == glo.signum() {
                        (lo, glo) = (mid, gm);
                    } else {
                        hi = mid;
                    }
                }
                let (_, uv, t) = g(0.5 * (lo + hi)).unwrap();
                roots.push((uv, t));
            }
        }
        roots
    }

    #[test]
    fn rolling_shutter_projection_matches_a_brute_force_search_over_rows() {
        let camera = p30_like(960, 540);
        // A fast pan (up to 60 °/s) to make the rows matter: tens of pixels of shear.
        let config = MotionConfig {
            angular_speed_deg_s: [40.0, 60.0],
            linear_speed_m_s: [0.3, 0.5],
            ..Default::default()
        };
        let tr = lab_trajectory(&config);
        let mut checked = 0;
        let mut largest_shift: f64 = 0.0;
        for k in 0..6 {
            let shutter = Shutter {
                time_s: f64::from(k),
                readout_s: 0.03,
                exposure_s: 0.008,
            };
            let pose = tr.cam_from_world(shutter.time_s);
            let centre = camera_centre(&pose);
            let axis = pose.rotation.inverse() * Vector3::z();
            for (i, j) in [
                (-0.4, -0.2),
                (0.0, 0.0),
                (0.3, 0.25),
                (-0.2, 0.3),
                (0.45, -0.25),
            ] {
                let right = pose.rotation.inverse() * Vector3::x();
                let down = pose.rotation.inverse() * Vector3::y();
                let p = centre.coords + (axis + right * i + down * j) * 2.5;
                let exact =
                    project_rolling_shutter(&camera, &shutter, |t| tr.cam_from_world(t), &p, None)
                        .unwrap();
                let roots = brute_force(&camera, &shutter, &tr, &p);
                assert_eq!(roots.len(), 1, "one row sees the point: {roots:?}");
                let (uv, t) = roots[0];
                assert!(
                    (exact.uv - uv).norm() < 1e-6,
                    "{:?} vs brute force {uv:?}",
                    exact.uv
                );
                assert!((exact.time_s - t).abs() < 1e-9);
                let global = camera.project_world(&pose, &p).unwrap();
                largest_shift = largest_shift.max((global - exact.uv).norm());
                checked += 1;
            }
        }
        assert_eq!(checked, 30);
        println!("largest rolling-shutter shift {largest_shift:.2} px");
        // The test is not trivial: rolling shutter moves the points by pixels.
        assert!(
            largest_shift > 2.0,
            "largest rolling-shutter shift {largest_shift} px"
        );
    }

    #[test]
    fn global_shutter_projection_is_the_frame_time_projection() {
        let camera = BrownCamera {
            width: 640,
            height: 480,
            intrinsics: Intrinsics::pinhole(500.0, 320.0, 240.0),
        };
        let tr = lab_trajectory(&MotionConfig::default());
        let shutter = Shutter {
            readout_s: 0.0,
            ..Shutter::global(2.0)
        };
        let pose = tr.cam_from_world(2.0);
        let p =
            camera_centre(&pose).coords + pose.rotation.inverse() * Vector3::new(0.1, -0.2, 2.0);
        let rs =
            project_rolling_shutter(&camera, &shutter, |t| tr.cam_from_world(t), &p, None).unwrap();
        assert_eq!(rs.uv, camera.project_world(&pose, &p).unwrap());
        assert_eq!(rs.time_s, 2.0);
    }

    #[test]
    fn pose_table_interpolates_the_trajectory_to_well_below_a_nanoradian() {
        let tr = lab_trajectory(&MotionConfig::default());
        let shutter = Shutter {
            time_s: 3.0,
            readout_s: 0.025,
            exposure_s: 0.008,
        };
        let (t0, t1) = shutter.span();
        let table = PoseTable::new(|t| tr.cam_from_world(t), t0, t1);
        let mut worst: (f64, f64) = (0.0, 0.0);
        for k in 0..997 {
            let t = t0 + (t1 - t0) * f64::from(k) / 996.0;
            let (o, q) = table.at(t);
            let pose = tr.cam_from_world(t);
            worst.0 = worst.0.max(q.angle_to(&pose.rotation.inverse()));
            worst.1 = worst.1.max((o - camera_centre(&pose)).norm());
        }
        println!("pose table error {worst:?} (rad, m)");
        assert!(worst.0 < 1e-9 && worst.1 < 1e-9, "worst {worst:?} (rad, m)");
        let fixed = PoseTable::fixed(&tr.cam_from_world(1.0));
        assert_eq!(fixed.at(7.0).0, camera_centre(&tr.cam_from_world(1.0)));
    }
}
