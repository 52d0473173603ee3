//! Continuous camera trajectories for simulated video: `cam_from_world(t)` with analytic
//! velocities, through the scene's stations (the frames of the 1 fps extraction), with
//! hand-held velocities at the stations, pauses between them and hand tremor.
//!
//! # Motion convention
//!
//! The angular velocity ω and the linear velocity ν at time t are expressed in the *camera*
//! frame and defined by the first-order motion of a static world point X in camera coordinates:
//!
//! ```text
//! p_cam(t + s) ≈ exp(s·[ω]×)·p_cam(t) + s·ν,      p_cam(t) = R(t)·X + T(t)
//! [ω]× = Ṙ·Rᵀ,   ν = Ṫ − ω × T = −R·Ċ              (C = −Rᵀ·T, the camera centre)
//! ```
//!
//! so |ν| is the speed of the camera centre (m/s) and |ω| the angular speed (rad/s).
//!
//! # Construction
//!
//! Between two knots (tᵃ, Rᵃ, Cᵃ, ωᵃ, Ċᵃ) and (tᵇ, …) of a segment of length Δ = tᵇ − tᵃ,
//! with s = (t − tᵃ)/Δ:
//!
//! * the centre is the Hermite curve through Cᵃ, Cᵇ with tangents Δ·Ċᵃ, Δ·Ċᵇ;
//! * the rotation is `R(t) = exp([φ(s)]×)·Rᵃ`, φ the Hermite curve in the segment's tangent
//!   space with φ(0) = 0, φ(1) = φᵇ = log(Rᵇ·Rᵃᵀ), φ'(0) = Δ·ωᵃ and φ'(1) = Δ·J_l(φᵇ)⁻¹·ωᵇ.
//!   Since `d exp(φ) = [J_l(φ)·dφ]× exp(φ)` (J_l the left Jacobian of SO(3); the
//!   "right-Jacobian correction" of right-perturbed conventions, J_l(φ) = J_r(−φ)),
//!   ω(t) = J_l(φ(s))·φ'(s)/Δ, which takes the prescribed values at both knots and is continuous
//!   across them (Kim, Kim & Shin, "A general construction scheme for unit quaternion curves",
//!   SIGGRAPH 1995; Sola, Deray & Atchuthan, "A micro Lie theory for state estimation in
//!   robotics", arXiv:1812.01537, eq. 143–146 for J_l and its inverse).
//!
//! The Hermite curves are *quintic* with zero second derivative at both knots, not cubic: a
//! cubic's acceleration at a knot is set by the segment's displacement, and the lab's 90° turn
//! from portrait to landscape within one interval then accelerates the camera at ≈ 30 rad/s²
//! at the frames beside it (14 °/s of change within one 8 ms exposure).
//!
//! A quintic knot is only C²: the jerk jumps there, and a knot at a station puts that jump
//! exactly at the time the frame is taken — something no hand does (it does not know when the
//! 1 fps extraction samples it), and exactly where a calibration expands each frame's motion
//! (over ±1/30 s to the neighbouring video frames the jump left 0.04 px RMS that no smooth
//! motion fits at 4K, and 0.13 px of camera error on the iPhone 11 lab from the true
//! projections alone). So a station with a **pause on both sides** is passed by *one movement
//! from rest to rest*: from the end of the pause before it to the start of the pause after it,
//! the rotation (in the station's tangent space, `R(t) = exp([φ(t)]×)·Rˢ`) and the centre are
//! polynomials of degree 8 with the station's pose and velocities and no acceleration at the
//! station (the steady hand at a viewpoint, as with the knots; left free, the polynomial of
//! degree 7 accelerated some frames by up to 460 °/s², 9 °/s within one readout) and zero
//! velocity and acceleration at both rests (the rests' jerk jumps, as a movement starting from
//! rest does; Flash & Hogan, "The coordination of arm movements", J. Neurosci. 1985). The
//! motion is then smooth through such a station. Stations beside a turn without a pause, and
//! the first and the last, keep the quintic knots: no acceleration at them (exactly at a
//! segment's start; at its end up to a term of order |φᵇ|·|ω|², below 0.01 rad/s²).
//!
//! Hand tremor multiplies the rotation on the left (about axes fixed in the phone):
//! `R(t) = exp([δ(t)]×)·R_h(t)` with `δ(t) = Σᵢ aᵢ·uᵢ·sin(2π·fᵢ·t + ψᵢ)`, a few sinusoids of
//! 4–12 Hz (physiological hand tremor: Elble & Koller, "Tremor", 1990), so that
//! `ω = J_l(δ)·δ̇ + exp(δ)·ω_h`. The tremor-free knots are set so that the *total* pose and
//! velocities at every station are the station's pose and the drawn velocities exactly.
//!
//! Before the first knot and after the last the motion continues at the end knot's velocity.

use nalgebra::{Matrix3, Point3, Quaternion, Translation3, UnitQuaternion, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::geometry::Rigid3;
use crate::geometry::pose::{camera_centre, skew};

/// How the hand-held camera moves.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MotionConfig {
    /// Range of the angular speed at the stations (°/s), drawn uniformly about a uniformly
    /// random axis; default 3–9 °/s (a careful hand-held video).
    pub angular_speed_deg_s: [f64; 2],
    /// Range of the camera's speed at the stations (m/s), drawn uniformly in a uniformly random
    /// direction; default 0.05–0.15 m/s.
    pub linear_speed_m_s: [f64; 2],
    /// RMS angular rate of the hand tremor (°/s), default 0.5; 0 = none.
    pub tremor_deg_s: f64,
    /// Length of the pause between two stations (s): the camera rests at a viewpoint (tremor
    /// only) for this long somewhere in the middle half of each interval and moves faster
    /// before and after (not in an interval that turns the phone by more than 45°). Default
    /// 0.2 s; 0 = no pauses.
    pub pause_s: f64,
}

impl Default for MotionConfig {
    fn default() -> Self {
        MotionConfig {
            angular_speed_deg_s: [3.0, 9.0],
            linear_speed_m_s: [0.05, 0.15],
            tremor_deg_s: 0.5,
            pause_s: 0.2,
        }
    }
}

/// Why a motion configuration is unusable.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("motion option `{field}`: {reason}")]
pub struct MotionConfigError {
    /// The option.
    pub field: &'static str,
    /// What is wrong.
    pub reason: String,
}

impl MotionConfig {
    /// Checks the values for stations `interval_s` apart.
    ///
    /// # Errors
    ///
    /// [`MotionConfigError`] naming the first bad option.
    pub fn validate(&self, interval_s: f64) -> Result<(), MotionConfigError> {
        let bad = |field, reason: String| Err(MotionConfigError { field, reason });
        for (field, [lo, hi], max) in [
            ("angular_speed_deg_s", self.angular_speed_deg_s, 180.0),
            ("linear_speed_m_s", self.linear_speed_m_s, 5.0),
        ] {
            if !(lo.is_finite() && hi.is_finite() && 0.0 <= lo && lo <= hi && hi <= max) {
                return bad(
                    field,
                    format!("needs 0 ≤ min ≤ max ≤ {max}, got {lo}, {hi}"),
                );
            }
        }
        if !(self.tremor_deg_s.is_finite() && (0.0..=20.0).contains(&self.tremor_deg_s)) {
            return bad("tremor_deg_s", "must be between 0 and 20 °/s".into());
        }
        if !(self.pause_s.is_finite() && self.pause_s >= 0.0 && self.pause_s <= 0.4 * interval_s) {
            return bad(
                "pause_s",
                format!(
                    "must be between 0 and 0.4 × the frame interval ({} s)",
                    0.4 * interval_s
                ),
            );
        }
        Ok(())
    }
}

/// A knot of the tremor-free motion.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Knot {
    /// Time (s).
    pub time_s: f64,
    /// Tremor-free rotation of `cam_from_world`, quaternion (w, x, y, z).
    pub qvec: [f64; 4],
    /// Camera centre (world, m).
    pub centre: [f64; 3],
    /// Tremor-free angular velocity ω_h (camera frame, rad/s).
    pub angular_velocity: [f64; 3],
    /// Velocity of the camera centre Ċ (world frame, m/s).
    pub centre_velocity: [f64; 3],
    /// A pause's start or end: the camera rests there (no velocity, no acceleration). A
    /// station between two rest knots is passed by one smooth movement from rest to rest
    /// ([`Trajectory::motion`]); absent (false) in truth files written before it existed,
    /// which are then evaluated as they were written.
    #[serde(default)]
    pub rest: bool,
}

/// One sinusoid of the hand tremor: `δ(t) += amplitude·axis·sin(2π·frequency·t + phase)`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct TremorTerm {
    /// Unit rotation axis in the camera frame.
    pub axis: [f64; 3],
    /// Amplitude (rad).
    pub amplitude_rad: f64,
    /// Frequency (Hz).
    pub frequency_hz: f64,
    /// Phase (rad).
    pub phase_rad: f64,
}

/// The camera's pose and velocities at one time (see the module documentation).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Motion {
    /// `cam_from_world`.
    pub cam_from_world: Rigid3,
    /// ω, camera frame (rad/s).
    pub angular_velocity: Vector3<f64>,
    /// ν, camera frame (m/s).
    pub linear_velocity: Vector3<f64>,
}

/// A continuous, time-parametrised camera trajectory (serialisable: the truth file holds it,
/// so that `cam_from_world(t)` can be recomputed from the truth alone).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Trajectory {
    /// Knots of the tremor-free motion, by increasing time.
    pub knots: Vec<Knot>,
    /// Hand tremor.
    pub tremor: Vec<TremorTerm>,
}

/// Number of tremor sinusoids.
const TREMOR_TERMS: usize = 3;
/// Frequency band of physiological hand tremor (Hz), Elble & Koller 1990.
const TREMOR_BAND_HZ: (f64, f64) = (4.0, 12.0);
/// Where the middle of a pause may fall within an interval (fraction of the interval).
const PAUSE_PHASE: (f64, f64) = (0.25, 0.75);
/// Intervals turning the phone by more than this (rad; 45°) have no pause: the turn (the lab's
/// and the site's 90° roll from portrait to landscape) takes the whole interval rather than a
/// violent fraction of it.
const PAUSE_MAX_TURN_RAD: f64 = std::f64::consts::FRAC_PI_4;

/// Left Jacobian of SO(3): `exp(φ + δ) ≈ exp(J_l(φ)·δ)·exp(φ)` (Sola et al. 2018, eq. 145).
#[must_use]
pub fn left_jacobian(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = phi.norm_squared();
    let k = skew(phi);
    if theta2 < 1e-12 {
        return Matrix3::identity() + k * 0.5 + k * k / 6.0;
    }
    let theta = theta2.sqrt();
    let half = (theta / 2.0).sin();
    // (1 − cos θ)/θ² written as 2 sin²(θ/2)/θ² to avoid cancellation.
    Matrix3::identity()
        + k * (2.0 * half * half / theta2)
        + k * k * ((theta - theta.sin()) / (theta2 * theta))
}

/// Inverse of [`left_jacobian`] (Sola et al. 2018, eq. 146), for |φ| < 2π.
#[must_use]
pub fn left_jacobian_inverse(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = phi.norm_squared();
    let k = skew(phi);
    if theta2 < 1e-12 {
        return Matrix3::identity() - k * 0.5 + k * k / 12.0;
    }
    let theta = theta2.sqrt();
    let coeff = 1.0 / theta2 - (1.0 + theta.cos()) / (2.0 * theta * theta.sin());
    Matrix3::identity() - k * 0.5 + k * k * coeff
}

fn quat(q: [f64; 4]) -> UnitQuaternion<f64> {
    UnitQuaternion::from_quaternion(Quaternion::new(q[0], q[1], q[2], q[3]))
}

fn qvec(q: &UnitQuaternion<f64>) -> [f64; 4] {
    [q.w, q.i, q.j, q.k]
}

/// A uniformly distributed unit vector.
fn random_unit(rng: &mut ChaCha8Rng) -> Vector3<f64> {
    loop {
        let v = Vector3::new(
            crate::robust::standard_normal(rng),
            crate::robust::standard_normal(rng),
            crate::robust::standard_normal(rng),
        );
        let n = v.norm();
        if n > 1e-6 {
            return v / n;
        }
    }
}

/// The tremor-free state at a time: rotation, centre, ω_h (camera frame), Ċ (world).
#[derive(Clone, Copy, Debug)]
struct State {
    rotation: UnitQuaternion<f64>,
    centre: Vector3<f64>,
    angular_velocity: Vector3<f64>,
    centre_velocity: Vector3<f64>,
}

impl Trajectory {
    /// A camera resting at `cam_from_world` (no knot velocity, no tremor).
    #[must_use]
    pub fn stationary(cam_from_world: &Rigid3) -> Self {
        Trajectory {
            knots: vec![Knot {
                time_s: 0.0,
                qvec: qvec(&cam_from_world.rotation),
                centre: camera_centre(cam_from_world).coords.into(),
                angular_velocity: [0.0; 3],
                centre_velocity: [0.0; 3],
                rest: false,
            }],
            tremor: Vec::new(),
        }
    }

    /// A trajectory through `poses` (station k at time `k·interval_s`) moving as `config`
    /// says: at every station the pose is the station's and the angular and linear speeds are
    /// drawn (seeded) in the configured ranges about and along random directions; between two
    /// stations the camera pauses (`config.pause_s`) at a point of the Hermite curve; tremor
    /// throughout.
    ///
    /// # Panics
    ///
    /// If `poses` is empty or `interval_s` is not positive (programmer errors: the scenes
    /// always have frames, and the configuration is validated first).
    #[must_use]
    pub fn through(poses: &[Rigid3], interval_s: f64, config: &MotionConfig, seed: u64) -> Self {
        assert!(
            !poses.is_empty() && interval_s > 0.0,
            "a trajectory needs stations"
        );
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7BA1_EC70);
        let rate = config.tremor_deg_s.to_radians();
        let tremor: Vec<TremorTerm> = if rate > 0.0 {
            (0..TREMOR_TERMS)
                .map(|_| {
                    let frequency_hz = rng.random_range(TREMOR_BAND_HZ.0..=TREMOR_BAND_HZ.1);
                    let axis = random_unit(&mut rng);
                    let phase_rad = rng.random_range(0.0..std::f64::consts::TAU);
                    // Peak rate aᵢ·2πfᵢ = rate·√(2/n): the sum's RMS rate is `rate`
                    // (sinusoids of different frequencies are uncorrelated over time).
                    let peak_rate = rate * (2.0 / TREMOR_TERMS as f64).sqrt();
                    TremorTerm {
                        axis: axis.into(),
                        amplitude_rad: peak_rate / (std::f64::consts::TAU * frequency_hz),
                        frequency_hz,
                        phase_rad,
                    }
                })
                .collect()
        } else {
            Vec::new()
        };
        let mut trajectory = Trajectory {
            knots: Vec::with_capacity(poses.len()),
            tremor,
        };
        let [w_lo, w_hi] = config.angular_speed_deg_s;
        let [v_lo, v_hi] = config.linear_speed_m_s;
        for (k, pose) in poses.iter().enumerate() {
            let time_s = k as f64 * interval_s;
            let omega = random_unit(&mut rng) * rng.random_range(w_lo..=w_hi).to_radians();
            let nu = random_unit(&mut rng) * rng.random_range(v_lo..=v_hi);
            // Remove the tremor at the station: R = E·R_h and ω = J_l(δ)·δ̇ + E·ω_h.
            let (delta, delta_dot) = trajectory.tremor_at(time_s);
            let e = UnitQuaternion::from_scaled_axis(delta);
            let rotation = e.inverse() * pose.rotation;
            let omega_h = e.inverse() * (omega - left_jacobian(&delta) * delta_dot);
            trajectory.knots.push(Knot {
                time_s,
                qvec: qvec(&rotation),
                centre: camera_centre(pose).coords.into(),
                angular_velocity: omega_h.into(),
                // ν = −R·Ċ at the station.
                centre_velocity: (-(pose.rotation.inverse() * nu)).into(),
                rest: false,
            });
        }
        if config.pause_s > 0.0 && poses.len() > 1 {
            let plain = trajectory.knots.clone();
            let mut knots = Vec::with_capacity(3 * plain.len());
            for pair in plain.windows(2) {
                knots.push(pair[0]);
                let phase = rng.random_range(PAUSE_PHASE.0..=PAUSE_PHASE.1);
                let turn = quat(pair[1].qvec).angle_to(&quat(pair[0].qvec));
                if turn > PAUSE_MAX_TURN_RAD {
                    continue;
                }
                let middle = pair[0].time_s + phase * (pair[1].time_s - pair[0].time_s);
                let s = hermite(&pair[0], &pair[1], middle);
                for time_s in [middle - config.pause_s / 2.0, middle + config.pause_s / 2.0] {
                    knots.push(Knot {
                        time_s,
                        qvec: qvec(&s.rotation),
                        centre: s.centre.into(),
                        angular_velocity: [0.0; 3],
                        centre_velocity: [0.0; 3],
                        rest: true,
                    });
                }
            }
            knots.extend(plain.last().copied());
            trajectory.knots = knots;
        }
        trajectory
    }

    /// Tremor rotation δ(t) and its rate δ̇(t) (camera frame).
    fn tremor_at(&self, t: f64) -> (Vector3<f64>, Vector3<f64>) {
        let mut delta = Vector3::zeros();
        let mut rate = Vector3::zeros();
        for term in &self.tremor {
            let w = std::f64::consts::TAU * term.frequency_hz;
            let (s, c) = (w * t + term.phase_rad).sin_cos();
            let axis = Vector3::from(term.axis);
            delta += axis * (term.amplitude_rad * s);
            rate += axis * (term.amplitude_rad * w * c);
        }
        (delta, rate)
    }

    /// The tremor-free state at time t.
    fn state(&self, t: f64) -> State {
        let knots = &self.knots;
        let last = knots.len() - 1;
        let extrapolate = |k: &Knot, dt: f64| {
            let omega = Vector3::from(k.angular_velocity);
            let v = Vector3::from(k.centre_velocity);
            State {
                rotation: UnitQuaternion::from_scaled_axis(omega * dt) * quat(k.qvec),
                centre: Vector3::from(k.centre) + v * dt,
                angular_velocity: omega,
                centre_velocity: v,
            }
        };
        if t <= knots[0].time_s {
            return extrapolate(&knots[0], t - knots[0].time_s);
        }
        if t >= knots[last].time_s {
            return extrapolate(&knots[last], t - knots[last].time_s);
        }
        // knots[i].time_s ≤ t < knots[i + 1].time_s.
        // (A NaN time falls through the comparisons above: the first segment.)
        let i = knots.partition_point(|k| k.time_s <= t).saturating_sub(1);
        self.movement(i)
            .and_then(|(a, s, b)| through_station(a, s, b, t))
            .unwrap_or_else(|| hermite(&knots[i], &knots[i + 1], t))
    }

    /// The movement from rest to rest through a station that the segment starting at knot `i`
    /// belongs to: (rest, station, rest), when the station has a pause on both sides.
    fn movement(&self, i: usize) -> Option<(&Knot, &Knot, &Knot)> {
        let k = &self.knots;
        let (here, next) = (k.get(i)?, k.get(i + 1)?);
        if here.rest && !next.rest && k.get(i + 2).is_some_and(|b| b.rest) {
            return Some((here, next, &k[i + 2]));
        }
        if !here.rest && next.rest && i > 0 && k[i - 1].rest {
            return Some((&k[i - 1], here, next));
        }
        None
    }

    /// The pose and velocities at time t (seconds).
    #[must_use]
    pub fn motion(&self, t: f64) -> Motion {
        let h = self.state(t);
        let (delta, delta_dot) = self.tremor_at(t);
        let e = UnitQuaternion::from_scaled_axis(delta);
        let rotation = e * h.rotation;
        let angular_velocity = left_jacobian(&delta) * delta_dot + e * h.angular_velocity;
        let translation = -(rotation * h.centre);
        Motion {
            cam_from_world: Rigid3::from_parts(Translation3::from(translation), rotation),
            angular_velocity,
            linear_velocity: -(rotation * h.centre_velocity),
        }
    }

    /// `cam_from_world` at time t (seconds).
    #[must_use]
    pub fn cam_from_world(&self, t: f64) -> Rigid3 {
        self.motion(t).cam_from_world
    }

    /// The camera centre at time t (world).
    #[must_use]
    pub fn centre(&self, t: f64) -> Point3<f64> {
        Point3::from(self.state(t).centre)
    }
}

/// The tremor-free state at time t of the movement from the rest knot `a` through the station
/// `s` to the rest knot `b`: in the station's tangent space, `R(t) = exp([φ(t)]×)·Rˢ` and the
/// centre, each a polynomial of degree 8 in `t − tˢ` with the station's pose and velocities and
/// no acceleration at `tˢ` (φ = 0, φ̇ = ωˢ since `J_l(0) = I`, φ̈ = 0) and the rest knots'
/// poses with zero velocity and acceleration at both ends — smooth (C^∞) through the station,
/// where the frame is taken: a hand does not know when the video's 1 fps extraction samples
/// it. `None` only if the 6 × 6 system is singular (the knots' times coincide; never for a
/// validated pause).
fn through_station(a: &Knot, s: &Knot, b: &Knot, t: f64) -> Option<State> {
    let span = (s.time_s - a.time_s).max(b.time_s - s.time_s);
    let (xa, xb, x) = (
        (a.time_s - s.time_s) / span,
        (b.time_s - s.time_s) / span,
        (t - s.time_s) / span,
    );
    // Rows: value, first and second derivative at xa, then at xb, of the powers x³…x⁸ (no x²
    // term: no acceleration at the station).
    let mut m = nalgebra::Matrix6::zeros();
    for (r, &xe) in [xa, xb].iter().enumerate() {
        for (c, i) in (3..9).enumerate() {
            let fi = f64::from(i);
            m[(3 * r, c)] = xe.powi(i);
            m[(3 * r + 1, c)] = fi * xe.powi(i - 1);
            m[(3 * r + 2, c)] = fi * (fi - 1.0) * xe.powi(i - 2);
        }
    }
    let rs = quat(s.qvec);
    let (cs, w1, v1) = (
        Vector3::from(s.centre),
        Vector3::from(s.angular_velocity) * span,
        Vector3::from(s.centre_velocity) * span,
    );
    // Right-hand sides, one column per channel: φ (3), then the centre's offset from the
    // station's (3); the linear terms (x·w1, x·v1) moved to the right.
    let mut rhs = nalgebra::Matrix6::zeros();
    for (r, (knot, xe)) in [(a, xa), (b, xb)].into_iter().enumerate() {
        let phi = (quat(knot.qvec) * rs.inverse()).scaled_axis();
        let offset = Vector3::from(knot.centre) - cs;
        for axis in 0..3 {
            rhs[(3 * r, axis)] = phi[axis] - w1[axis] * xe;
            rhs[(3 * r + 1, axis)] = -w1[axis];
            rhs[(3 * r, 3 + axis)] = offset[axis] - v1[axis] * xe;
            rhs[(3 * r + 1, 3 + axis)] = -v1[axis];
        }
    }
    let coeffs = m.lu().solve(&rhs)?;
    let (mut value, mut rate) = (nalgebra::Vector6::zeros(), nalgebra::Vector6::zeros());
    for (c, i) in (3..9).enumerate() {
        value += coeffs.row(c).transpose() * x.powi(i);
        rate += coeffs.row(c).transpose() * (f64::from(i) * x.powi(i - 1));
    }
    let phi = value.fixed_rows::<3>(0) + w1 * x;
    let phi_dot = (rate.fixed_rows::<3>(0) + w1) / span;
    Some(State {
        rotation: UnitQuaternion::from_scaled_axis(phi) * rs,
        centre: cs + value.fixed_rows::<3>(3) + v1 * x,
        angular_velocity: left_jacobian(&phi) * phi_dot,
        centre_velocity: (rate.fixed_rows::<3>(3) + v1) / span,
    })
}

/// The quintic Hermite state between knots `a` and `b` at time t, zero second derivative at
/// both knots (module documentation).
fn hermite(a: &Knot, b: &Knot, t: f64) -> State {
    let dt = b.time_s - a.time_s;
    let s = (t - a.time_s) / dt;
    let (s2, s3, s4, s5) = (s * s, s * s * s, s * s * s * s, s * s * s * s * s);
    // Quintic Hermite basis of (p₀, v₀, p₁, v₁) with the accelerations' terms left out (zero).
    let (h00, h10, h01, h11) = (
        1.0 - 10.0 * s3 + 15.0 * s4 - 6.0 * s5,
        s - 6.0 * s3 + 8.0 * s4 - 3.0 * s5,
        10.0 * s3 - 15.0 * s4 + 6.0 * s5,
        -4.0 * s3 + 7.0 * s4 - 3.0 * s5,
    );
    let (d00, d10, d01, d11) = (
        -30.0 * s2 + 60.0 * s3 - 30.0 * s4,
        1.0 - 18.0 * s2 + 32.0 * s3 - 15.0 * s4,
        30.0 * s2 - 60.0 * s3 + 30.0 * s4,
        -12.0 * s2 + 28.0 * s3 - 15.0 * s4,
    );
    let (ca, cb) = (Vector3::from(a.centre), Vector3::from(b.centre));
    let (va, vb) = (
        Vector3::from(a.centre_velocity) * dt,
        Vector3::from(b.centre_velocity) * dt,
    );
    let centre = ca * h00 + va * h10 + cb * h01 + vb * h11;
    let centre_velocity = (ca * d00 + va * d10 + cb * d01 + vb * d11) / dt;

    let (ra, rb) = (quat(a.qvec), quat(b.qvec));
    let phi_b = (rb * ra.inverse()).scaled_axis();
    let m0 = Vector3::from(a.angular_velocity) * dt;
    let m1 = left_jacobian_inverse(&phi_b) * Vector3::from(b.angular_velocity) * dt;
    let phi = m0 * h10 + phi_b * h01 + m1 * h11;
    let phi_dot = (m0 * d10 + phi_b * d01 + m1 * d11) / dt;
    State {
        rotation: UnitQuaternion::from_scaled_axis(phi) * ra,
        centre,
        angular_velocity: left_jacobian(&phi) * phi_dot,
        centre_velocity,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::lab::{LabConfig, path};

    fn lab_poses(frames: usize) -> Vec<Rigid3> {
        let cfg = LabConfig {
            frames,
            ..Default::default()
        };
        path(&cfg, 3)
            .into_iter()
            .map(|s| s.cam_from_world)
            .collect()
    }

    /// ω and ν by central differences of the poses (independent of the analytic velocities):
    /// ω from log(R(t+h)·R(t−h)ᵀ)/2h, ν = Ṫ − ω × T.
    fn finite_difference(tr: &Trajectory, t: f64, h: f64) -> (Vector3<f64>, Vector3<f64>) {
        let (a, b, m) = (
            tr.cam_from_world(t - h),
            tr.cam_from_world(t + h),
            tr.cam_from_world(t),
        );
        let omega = (b.rotation * a.rotation.inverse()).scaled_axis() / (2.0 * h);
        let t_dot = (b.translation.vector - a.translation.vector) / (2.0 * h);
        (omega, t_dot - omega.cross(&m.translation.vector))
    }

    #[test]
    fn left_jacobian_matches_differences_of_the_exponential_and_its_inverse() {
        let phi = Vector3::new(0.7, -1.1, 0.4);
        let j = left_jacobian(&phi);
        let h = 1e-6;
        for k in 0..3 {
            let mut d = Vector3::zeros();
            d[k] = h;
            let plus = UnitQuaternion::from_scaled_axis(phi + d);
            let minus = UnitQuaternion::from_scaled_axis(phi - d);
            // exp(φ + δ)·exp(φ − δ)ᵀ ≈ exp(2·J_l·δ).
            let col = (plus * minus.inverse()).scaled_axis() / (2.0 * h);
            assert!(
                (col - j.column(k)).norm() < 1e-8,
                "column {k}: {col} vs {}",
                j.column(k)
            );
        }
        let inv = left_jacobian_inverse(&phi);
        assert!((inv * j - Matrix3::identity()).norm() < 1e-12);
        let small = Vector3::new(1e-7, -2e-7, 3e-8);
        assert!(
            (left_jacobian_inverse(&small) * left_jacobian(&small) - Matrix3::identity()).norm()
                < 1e-14
        );
    }

    #[test]
    fn velocities_agree_with_finite_differences_of_the_poses() {
        let poses = lab_poses(8);
        let tr = Trajectory::through(&poses, 1.0, &MotionConfig::default(), 11);
        let mut times: Vec<f64> = (0..140).map(|k| -0.3 + f64::from(k) * 0.0537).collect();
        times.extend(tr.knots.iter().map(|k| k.time_s + 1e-3));
        // Differences across a knot see the jump of the acceleration (the curve is C¹ there).
        times.retain(|t| tr.knots.iter().all(|k| (k.time_s - t).abs() > 1e-4));
        assert!(times.len() > 120);
        for t in times {
            let m = tr.motion(t);
            let (w, v) = finite_difference(&tr, t, 1e-5);
            // Central differences: error O(h²·third derivative) ≈ 1e-10·(≤ 1e3) ≪ 1e-6.
            assert!(
                (w - m.angular_velocity).norm() < 1e-6 * (1.0 + m.angular_velocity.norm()),
                "t = {t}: ω {} vs differences {w}",
                m.angular_velocity
            );
            assert!(
                (v - m.linear_velocity).norm() < 1e-6 * (1.0 + m.linear_velocity.norm()),
                "t = {t}: ν {} vs differences {v}",
                m.linear_velocity
            );
        }
    }

    #[test]
    fn stations_keep_their_poses_and_get_speeds_in_the_configured_ranges() {
        let poses = lab_poses(30);
        let config = MotionConfig::default();
        let tr = Trajectory::through(&poses, 1.0, &config, 5);
        // Two pause knots per interval but the one turning from portrait to landscape.
        assert_eq!(tr.knots.len(), 30 + 2 * 28);
        let (mut w_seen, mut v_seen) = (Vec::new(), Vec::new());
        for (k, pose) in poses.iter().enumerate() {
            let t = k as f64;
            let m = tr.cam_from_world(t);
            assert!(
                (m.rotation.angle_to(&pose.rotation)) < 1e-12,
                "station {k} rotation"
            );
            assert!((m.translation.vector - pose.translation.vector).norm() < 1e-12);
            let (w, v) = finite_difference(&tr, t, 1e-5);
            let w_deg = w.norm().to_degrees();
            assert!(
                (3.0 - 1e-6..=9.0 + 1e-6).contains(&w_deg),
                "station {k}: {w_deg} °/s"
            );
            assert!(
                (0.05 - 1e-8..=0.15 + 1e-8).contains(&v.norm()),
                "station {k}: {} m/s",
                v.norm()
            );
            w_seen.push(w_deg);
            v_seen.push(v.norm());
        }
        // The draws cover the ranges (30 uniform draws: min and max within a fifth of the ends).
        let span = |x: &[f64]| {
            (
                x.iter().copied().fold(f64::MAX, f64::min),
                x.iter().copied().fold(0.0, f64::max),
            )
        };
        let (lo, hi) = span(&w_seen);
        assert!(lo < 4.2 && hi > 7.8, "angular speeds {lo}–{hi} °/s");
        let (lo, hi) = span(&v_seen);
        assert!(lo < 0.07 && hi > 0.13, "speeds {lo}–{hi} m/s");
    }

    #[test]
    fn the_motion_is_smooth_through_the_stations_and_rests_at_the_pauses() {
        // Stations 3 and 4 of 8 frame the 90° turn from portrait to landscape, which has no
        // pause: they are quintic knots. Stations 1, 2, 5 and 6 have a pause on both sides and
        // are passed by one movement from rest to rest.
        let poses = lab_poses(8);
        let config = MotionConfig {
            tremor_deg_s: 0.0,
            ..Default::default()
        };
        let tr = Trajectory::through(&poses, 1.0, &config, 12);
        let w = |t: f64| tr.motion(t).angular_velocity;
        let v = |t: f64| tr.motion(t).linear_velocity;
        // One-sided second differences of ω from either side of t, (2f₀ − 5f₁ + 4f₂ − f₃)/h²:
        // ω̈(t) (the jerk of the rotation) to O(h²·|ω⁗|). At a knot of quintics the jerk jumps
        // between the two sides.
        let h = 1e-4;
        let jerks = |f: &dyn Fn(f64) -> Vector3<f64>, t: f64| {
            let side = |s: f64| {
                (f(t) * 2.0 - f(t + s * h) * 5.0 + f(t + 2.0 * s * h) * 4.0 - f(t + 3.0 * s * h))
                    / (h * h)
            };
            (side(-1.0), side(1.0))
        };
        let mut largest_jump = [0.0f64; 2];
        for k in [1, 2, 5, 6] {
            let t = f64::from(k);
            let (left, right) = jerks(&w, t);
            println!(
                "station {k}: jerk {:.3} | {:.3} rad/s³",
                left.norm(),
                right.norm()
            );
            largest_jump[0] = largest_jump[0].max((left - right).norm());
            let (left, right) = jerks(&v, t);
            largest_jump[1] = largest_jump[1].max((left - right).norm());
        }
        println!("largest jump of the jerk at a station: {largest_jump:?}");
        assert!(largest_jump[0] < 0.01, "{largest_jump:?}");
        assert!(largest_jump[1] < 0.01, "{largest_jump:?}");
        // The quintic knots beside the turn, measured the same way, do jump: the test can fail.
        let (left, right) = jerks(&w, 3.0);
        println!("station 3 (quintic knot): jerk {left} | {right}");
        assert!((left - right).norm() > 1.0, "{left} | {right}");
        // Rest knots: no velocity and no acceleration: ω and ν grow as ½·jerk·(t − tʳ)² away
        // from them, four times over twice the distance (twice with an acceleration).
        let rests: Vec<f64> = tr
            .knots
            .iter()
            .filter(|k| k.rest)
            .map(|k| k.time_s)
            .collect();
        assert_eq!(rests.len(), 2 * 6);
        for t in rests {
            assert!(w(t).norm() < 1e-12 && v(t).norm() < 1e-12, "rest at {t}");
            for dt in [-h, h] {
                for f in [&w as &dyn Fn(f64) -> Vector3<f64>, &v] {
                    let (near, far) = (f(t + dt).norm(), f(t + 2.0 * dt).norm());
                    // Inside the pause both are zero.
                    assert!(
                        far == 0.0 || (far / near - 4.0).abs() < 0.1,
                        "growth {} away from the rest at {t}",
                        far / near
                    );
                }
            }
        }
        // No station accelerates (beside the turn the quintic knots, elsewhere the movement's
        // own constraint); within the turn the camera does.
        // ν = −R·Ċ still changes with the rotation (|ω|·|Ċ| ≤ 0.16 × 0.15), and at a quintic
        // segment's end φ̈ leaves a term of order |φᵇ|·|ω|²: small.
        let rate =
            |f: &dyn Fn(f64) -> Vector3<f64>, t: f64| (f(t + 1e-6) - f(t - 1e-6)).norm() / 2e-6;
        for t in (0..8).map(f64::from) {
            assert!(rate(&w, t) < 0.05, "station {t}: {} rad/s²", rate(&w, t));
            assert!(rate(&v, t) < 0.03, "station {t}: {} m/s²", rate(&v, t));
        }
        assert!(
            rate(&w, 3.2) > 1.0,
            "{} rad/s² within the turn",
            rate(&w, 3.2)
        );
    }

    #[test]
    fn tremor_has_the_configured_rms_rate_and_tremor_band_frequencies() {
        let pose = lab_poses(2)[0];
        let mut tr = Trajectory::stationary(&pose);
        let other = Trajectory::through(
            &[pose],
            1.0,
            &MotionConfig {
                tremor_deg_s: 0.8,
                ..Default::default()
            },
            2,
        );
        tr.tremor = other.tremor;
        assert_eq!(tr.tremor.len(), 3);
        // The knot velocity of `other` is irrelevant here: the stationary knot has none.
        let n = 20_000;
        let sum: f64 = (0..n)
            .map(|k| {
                let t = f64::from(k) * 0.0013;
                finite_difference(&tr, t, 1e-5).0.norm_squared()
            })
            .sum();
        let rms = (sum / f64::from(n)).sqrt().to_degrees();
        // Cross terms of different frequencies average out over 26 s only to a few per cent.
        assert!((rms / 0.8 - 1.0).abs() < 0.1, "tremor RMS rate {rms} °/s");
        assert!(
            tr.tremor
                .iter()
                .all(|t| (4.0..=12.0).contains(&t.frequency_hz))
        );
    }

    #[test]
    fn pauses_make_the_steadiest_frame_per_second_much_steadier_than_a_fixed_phase() {
        let poses = lab_poses(40);
        let tr = Trajectory::through(&poses, 1.0, &MotionConfig::default(), 9);
        let speed = |t: f64| tr.motion(t).angular_velocity.norm().to_degrees();
        let fps = 25;
        let (mut steadiest, mut phase0, mut phase_half) = (0.0, 0.0, 0.0);
        for second in 0..39 {
            let frames: Vec<f64> = (0..fps)
                .map(|j| speed(f64::from(second) + f64::from(j) / f64::from(fps)))
                .collect();
            steadiest += frames.iter().copied().fold(f64::MAX, f64::min);
            phase0 += frames[0];
            phase_half += frames[12];
        }
        let (steadiest, phase0, phase_half) = (steadiest / 39.0, phase0 / 39.0, phase_half / 39.0);
        println!(
            "mean angular speed: steadiest {steadiest:.2} °/s, phase 0 {phase0:.2}, phase 0.5 {phase_half:.2}"
        );
        // Stations: uniform 3–9 °/s, mean 6; a pause holds the tremor only (0.5 °/s RMS).
        assert!((4.5..=7.5).contains(&phase0), "phase 0: {phase0} °/s");
        assert!(
            steadiest < 0.25 * phase0,
            "steadiest {steadiest} vs phase 0 {phase0} °/s"
        );
        assert!(
            steadiest < 0.25 * phase_half,
            "steadiest {steadiest} vs phase 0.5 {phase_half} °/s"
        );
    }

    #[test]
    fn extrapolation_and_a_single_station_continue_at_the_end_velocity() {
        let poses = lab_poses(3);
        let tr = Trajectory::through(
            &poses,
            1.0,
            &MotionConfig {
                tremor_deg_s: 0.0,
                ..Default::default()
            },
            4,
        );
        let m0 = tr.motion(0.0);
        let before = tr.motion(-0.5);
        assert!((before.angular_velocity - m0.angular_velocity).norm() < 1e-12);
        assert!((before.linear_velocity.norm() - m0.linear_velocity.norm()).abs() < 1e-12);
        let (w, _) = finite_difference(&tr, -0.5, 1e-5);
        assert!((w - before.angular_velocity).norm() < 1e-8);
        let still = Trajectory::stationary(&poses[1]);
        let p = still.cam_from_world(12.3);
        assert!(p.rotation.angle_to(&poses[1].rotation) < 1e-15);
        assert!((p.translation.vector - poses[1].translation.vector).norm() < 1e-12);
    }
}
