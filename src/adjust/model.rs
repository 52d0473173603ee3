//! Camera models the adjustment is generic over: each says how many intrinsics belong to one
//! camera (`local`, BAL's f, k1, k2) and how many are shared by every camera (`global`, the
//! ten `brown` intrinsics of a phone calibrated once per device), and projects a camera-frame
//! point with analytic Jacobians.

use nalgebra::{Matrix2x3, Vector2, Vector3};

use crate::camera::Intrinsics;
use crate::camera::rolling::{self, Motion, MotionOrder, RowTiming};

/// Where [`CameraModel::project`] writes its Jacobians.
#[derive(Debug)]
pub struct ModelJacobians<'a> {
    /// `∂uv/∂p_cam` (2×3).
    pub d_p_cam: &'a mut Matrix2x3<f64>,
    /// `∂uv/∂local`, row-major 2×`local_len`.
    pub d_local: &'a mut [f64],
    /// `∂uv/∂global`, row-major 2×`global_len`.
    pub d_global: &'a mut [f64],
}

/// A projection model for [`crate::adjust::Problem`].
pub trait CameraModel: Sync {
    /// Intrinsic parameters carried by each camera.
    fn local_len(&self) -> usize;
    /// Intrinsic parameters shared by every camera.
    fn global_len(&self) -> usize;
    /// Names of the shared parameters (for summaries).
    fn global_names(&self) -> Vec<&'static str>;
    /// Projects a camera-frame point with one camera's `local` and the shared `global`
    /// parameters, for an observation `time_offset_s` from the camera's frame time (a
    /// neighbouring video frame; models without motion ignore it), writing the Jacobians
    /// when asked; `None` where the model is undefined (behind the camera, outside the
    /// distortion's valid region).
    fn project(
        &self,
        local: &[f64],
        global: &[f64],
        p_cam: &Vector3<f64>,
        time_offset_s: f64,
        jacobians: Option<ModelJacobians<'_>>,
    ) -> Option<Vector2<f64>>;
    /// How one camera's `local` parameters change, to first order per unit `ε`, when the world
    /// is scaled by `1 + ε` (the scale column of the free network's inner constraints, which
    /// leave every image unchanged); written into `out` (`local_len` values). Default: they do
    /// not change (focal lengths, distortion).
    fn local_scale_direction(&self, _local: &[f64], out: &mut [f64]) {
        out.fill(0.0);
    }
    /// Applies a scaling of the world by `s` to one camera's `local` parameters (default:
    /// none of them is in world units).
    fn scale_local(&self, _local: &mut [f64], _s: f64) {}
}

/// The `brown` model with the ten intrinsics of [`crate::camera::Term::ALL`] shared by every
/// camera (one phone, one calibration); with a rolling shutter
/// ([`crate::camera::rolling`]), also each camera's motion (6 local values `(ω, ν)`, or up to
/// 24 with accelerations, jerks and snaps when neighbouring video frames are measured,
/// [`MotionOrder`]) and the shared readout time τ (the eleventh shared value,
/// [`BrownModel::READOUT`]).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BrownModel {
    /// The frames' height when they are read out row by row (rolling shutter); `None` for a
    /// global shutter.
    pub rolling_shutter: Option<RowHeight>,
    /// With a rolling shutter: the order of each camera's motion (first within a frame;
    /// higher for observations in neighbouring video frames `±1/fps` away).
    pub motion_order: MotionOrder,
}

/// The frame height (px) that maps a row to its time for [`BrownModel`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RowHeight(pub f64);

impl BrownModel {
    /// A global shutter: ten shared intrinsics, nothing per camera.
    pub const GLOBAL_SHUTTER: BrownModel = BrownModel {
        rolling_shutter: None,
        motion_order: MotionOrder::First,
    };
    /// Index of the readout time among the shared values of a rolling-shutter model.
    pub const READOUT: usize = 10;

    /// A rolling shutter on frames `height_px` rows high.
    #[must_use]
    pub fn rolling_shutter(height_px: f64) -> Self {
        BrownModel {
            rolling_shutter: Some(RowHeight(height_px)),
            motion_order: MotionOrder::First,
        }
    }

    /// A rolling shutter on frames `height_px` rows high with motions of `order`.
    #[must_use]
    pub fn rolling_shutter_of_order(height_px: f64, order: MotionOrder) -> Self {
        BrownModel {
            motion_order: order,
            ..Self::rolling_shutter(height_px)
        }
    }
}

impl CameraModel for BrownModel {
    fn local_len(&self) -> usize {
        match self.rolling_shutter {
            None => 0,
            Some(_) => self.motion_order.values(),
        }
    }

    fn global_len(&self) -> usize {
        if self.rolling_shutter.is_some() {
            11
        } else {
            10
        }
    }

    fn global_names(&self) -> Vec<&'static str> {
        let mut names: Vec<&'static str> =
            crate::camera::Term::ALL.iter().map(|t| t.name()).collect();
        if self.rolling_shutter.is_some() {
            names.push("readout");
        }
        names
    }

    fn project(
        &self,
        local: &[f64],
        global: &[f64],
        p_cam: &Vector3<f64>,
        time_offset_s: f64,
        jacobians: Option<ModelJacobians<'_>>,
    ) -> Option<Vector2<f64>> {
        let mut a = [0.0; 10];
        a.copy_from_slice(&global[..10]);
        let intrinsics = Intrinsics::from_array(a);
        let Some(RowHeight(height_px)) = self.rolling_shutter else {
            return match jacobians {
                None => intrinsics.project(p_cam),
                Some(j) => {
                    let p = intrinsics.project_with_jacobians(p_cam)?;
                    *j.d_p_cam = p.d_uv_d_p_cam;
                    for r in 0..2 {
                        for c in 0..10 {
                            j.d_global[r * 10 + c] = p.d_uv_d_intrinsics[(r, c)];
                        }
                    }
                    Some(p.uv)
                }
            };
        };
        let timing = RowTiming {
            readout_s: global[Self::READOUT],
            height_px,
        };
        let motion = Motion::from_slice(local);
        match jacobians {
            None => rolling::project(&intrinsics, &timing, &motion, p_cam, time_offset_s)
                .map(|(uv, _)| uv),
            Some(j) => {
                let p = rolling::project_with_jacobians(
                    &intrinsics,
                    &timing,
                    &motion,
                    p_cam,
                    time_offset_s,
                )?;
                *j.d_p_cam = p.d_uv_d_p0;
                let nl = self.local_len();
                for r in 0..2 {
                    for c in 0..nl {
                        j.d_local[r * nl + c] = p.d_uv_d_motion[(r, c)];
                    }
                    for c in 0..10 {
                        j.d_global[r * 11 + c] = p.d_uv_d_intrinsics[(r, c)];
                    }
                    j.d_global[r * 11 + Self::READOUT] = p.d_uv_d_readout[r];
                }
                Some(p.uv)
            }
        }
    }

    fn local_scale_direction(&self, local: &[f64], out: &mut [f64]) {
        out.fill(0.0);
        for block in rolling::WORLD_UNIT_BLOCKS {
            if let (Some(o), Some(l)) = (out.get_mut(block.clone()), local.get(block)) {
                o.copy_from_slice(l);
            }
        }
    }

    fn scale_local(&self, local: &mut [f64], s: f64) {
        for block in rolling::WORLD_UNIT_BLOCKS {
            if let Some(l) = local.get_mut(block) {
                for v in l {
                    *v *= s;
                }
            }
        }
    }
}

/// BAL's camera: per camera f, k1, k2; `p = −P/P.z`, `uv = f·(1 + k1·|p|² + k2·|p|⁴)·p`.
#[derive(Clone, Copy, Debug, Default)]
pub struct BalModel;

impl CameraModel for BalModel {
    fn local_len(&self) -> usize {
        3
    }

    fn global_len(&self) -> usize {
        0
    }

    fn global_names(&self) -> Vec<&'static str> {
        Vec::new()
    }

    fn project(
        &self,
        local: &[f64],
        _global: &[f64],
        p_cam: &Vector3<f64>,
        _time_offset_s: f64,
        jacobians: Option<ModelJacobians<'_>>,
    ) -> Option<Vector2<f64>> {
        if p_cam.z == 0.0 {
            return None;
        }
        let (f, k1, k2) = (local[0], local[1], local[2]);
        let iz = -1.0 / p_cam.z;
        let (x, y) = (p_cam.x * iz, p_cam.y * iz);
        let r2 = x * x + y * y;
        let radial = 1.0 + r2 * (k1 + k2 * r2);
        let uv = Vector2::new(f * radial * x, f * radial * y);
        if let Some(j) = jacobians {
            // d(radial)/d(r²)
            let dr = k1 + 2.0 * k2 * r2;
            // ∂uv/∂(x, y)
            let a = f * (radial + 2.0 * x * x * dr);
            let b = f * 2.0 * x * y * dr;
            let d = f * (radial + 2.0 * y * y * dr);
            // ∂(x, y)/∂P with x = X·iz, iz = −1/Z: ∂x/∂X = iz, ∂x/∂Z = X/Z² = x·iz.
            let dx = [iz, 0.0, x * iz];
            let dy = [0.0, iz, y * iz];
            for c in 0..3 {
                j.d_p_cam[(0, c)] = a * dx[c] + b * dy[c];
                j.d_p_cam[(1, c)] = b * dx[c] + d * dy[c];
            }
            j.d_local[0] = radial * x;
            j.d_local[1] = f * r2 * x;
            j.d_local[2] = f * r2 * r2 * x;
            j.d_local[3] = radial * y;
            j.d_local[4] = f * r2 * y;
            j.d_local[5] = f * r2 * r2 * y;
        }
        Some(uv)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Central differences of `project` against its analytic Jacobians.
    fn check_jacobians<M: CameraModel>(model: &M, local: &[f64], global: &[f64], p: Vector3<f64>) {
        let (nl, ng) = (model.local_len(), model.global_len());
        let mut dp = Matrix2x3::zeros();
        let mut dl = vec![0.0; 2 * nl];
        let mut dg = vec![0.0; 2 * ng];
        model
            .project(
                local,
                global,
                &p,
                0.02,
                Some(ModelJacobians {
                    d_p_cam: &mut dp,
                    d_local: &mut dl,
                    d_global: &mut dg,
                }),
            )
            .unwrap();
        let proj =
            |l: &[f64], g: &[f64], p: &Vector3<f64>| model.project(l, g, p, 0.02, None).unwrap();
        for c in 0..3 {
            let h = 1e-6 * p.norm();
            let (mut a, mut b) = (p, p);
            a[c] += h;
            b[c] -= h;
            let num = (proj(local, global, &a) - proj(local, global, &b)) / (2.0 * h);
            for r in 0..2 {
                assert!(
                    (num[r] - dp[(r, c)]).abs() < 1e-6 * (1.0 + num[r].abs()),
                    "p {r}{c}"
                );
            }
        }
        for k in 0..nl {
            let h = 1e-7 * (1.0 + local[k].abs());
            let (mut a, mut b) = (local.to_vec(), local.to_vec());
            a[k] += h;
            b[k] -= h;
            let num = (proj(&a, global, &p) - proj(&b, global, &p)) / (2.0 * h);
            for r in 0..2 {
                let an = dl[r * nl + k];
                assert!(
                    (num[r] - an).abs() < 1e-5 * (1.0 + an.abs()),
                    "local {k}: {num} {an}"
                );
            }
        }
        for k in 0..ng {
            let h = 1e-7 * (1.0 + global[k].abs());
            let (mut a, mut b) = (global.to_vec(), global.to_vec());
            a[k] += h;
            b[k] -= h;
            let num = (proj(local, &a, &p) - proj(local, &b, &p)) / (2.0 * h);
            for r in 0..2 {
                let an = dg[r * ng + k];
                assert!(
                    (num[r] - an).abs() < 1e-5 * (1.0 + an.abs()),
                    "global {k}: {num} {an}"
                );
            }
        }
    }

    #[test]
    fn bal_jacobians_match_central_differences() {
        check_jacobians(
            &BalModel,
            &[520.0, -0.08, 0.012],
            &[],
            Vector3::new(0.4, -0.3, -2.5),
        );
    }

    #[test]
    fn brown_jacobians_match_central_differences() {
        let i = [
            3000.0, 1930.0, 1075.0, 0.012, -0.009, 0.004, 1.6e-4, -2e-4, 0.3, -0.2,
        ];
        check_jacobians(
            &BrownModel::GLOBAL_SHUTTER,
            &[],
            &i,
            Vector3::new(0.3, -0.2, 1.7),
        );
    }

    /// The rolling-shutter `brown` model: motion (ω, ν) per camera, the readout time shared.
    #[test]
    fn rolling_shutter_brown_jacobians_match_central_differences() {
        let i = [
            3000.0, 1930.0, 1075.0, 0.012, -0.009, 0.004, 1.6e-4, -2e-4, 0.3, -0.2, 0.025,
        ];
        let motion = [0.05, -0.12, 0.03, 0.08, -0.02, 0.11];
        check_jacobians(
            &BrownModel::rolling_shutter(2160.0),
            &motion,
            &i,
            Vector3::new(0.3, -0.2, 1.7),
        );
    }

    /// The same with second- to fourth-order motions (ω, ν, α, a, ζ, j, σ, s) per camera.
    #[test]
    fn higher_order_rolling_shutter_brown_jacobians_match_central_differences() {
        let i = [
            3000.0, 1930.0, 1075.0, 0.012, -0.009, 0.004, 1.6e-4, -2e-4, 0.3, -0.2, 0.025,
        ];
        for order in [MotionOrder::Second, MotionOrder::Third, MotionOrder::Fourth] {
            check_jacobians(
                &BrownModel::rolling_shutter_of_order(2160.0, order),
                &HIGHER_ORDER_MOTION[..order.values()],
                &i,
                Vector3::new(0.3, -0.2, 1.7),
            );
        }
    }

    /// A hand-held motion to fourth order: velocities, accelerations, jerks, snaps.
    const HIGHER_ORDER_MOTION: [f64; 24] = [
        0.05, -0.12, 0.03, 0.08, -0.02, 0.11, 0.3, -0.2, 0.25, -0.4, 0.6, 0.2, 6.0, -4.0, 3.0,
        -8.0, 5.0, 2.0, 0.9, -0.6, 1.2, 0.4, -0.7, 0.3,
    ];

    /// Scaling the world by `s` scales `p_cam`, ν, a and j: the image stays the same, in the
    /// frame and in a neighbouring frame 1/25 s away.
    #[test]
    fn rolling_shutter_image_is_unchanged_by_a_scaled_world() {
        let g = [
            3000.0, 1930.0, 1075.0, 0.012, -0.009, 0.004, 1.6e-4, -2e-4, 0.3, -0.2, 0.025,
        ];
        for m in [
            BrownModel::rolling_shutter(2160.0),
            BrownModel::rolling_shutter_of_order(2160.0, MotionOrder::Second),
            BrownModel::rolling_shutter_of_order(2160.0, MotionOrder::Third),
            BrownModel::rolling_shutter_of_order(2160.0, MotionOrder::Fourth),
        ] {
            let n = m.local_len();
            let mut local = HIGHER_ORDER_MOTION[..n].to_vec();
            let p = Vector3::new(0.3, -0.2, 1.7);
            let before = m.project(&local, &g, &p, 0.04, None).unwrap();
            let mut direction = vec![0.0; n];
            m.local_scale_direction(&local, &mut direction);
            for (k, (d, l)) in direction.iter().zip(&local).enumerate() {
                let world_units = (k / 3) % 2 == 1;
                assert_eq!(*d, if world_units { *l } else { 0.0 }, "value {k}");
            }
            m.scale_local(&mut local, 2.5);
            let after = m.project(&local, &g, &(p * 2.5), 0.04, None).unwrap();
            assert!((after - before).norm() < 1e-9, "{before} {after}");
        }
    }

    #[test]
    fn bal_projection_follows_the_documented_formula() {
        // P = (1, 2, −4): p = −P/P.z = (0.25, 0.5), r² = 0.3125.
        let uv = BalModel
            .project(
                &[100.0, 0.1, 0.01],
                &[],
                &Vector3::new(1.0, 2.0, -4.0),
                0.0,
                None,
            )
            .unwrap();
        let radial = 1.0 + 0.1 * 0.3125 + 0.01 * 0.3125 * 0.3125;
        assert!((uv.x - 100.0 * radial * 0.25).abs() < 1e-12);
        assert!((uv.y - 100.0 * radial * 0.5).abs() < 1e-12);
    }
}
