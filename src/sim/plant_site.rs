//! A plant room as a photogrammetric site: the room of [`super::plant`] seen by the
//! camera (its parry3d compound rendered, observed and occluding through
//! [`super::scene::Solids`]), target boards on its four walls (their centres are the
//! TLS target list), lights under the ceiling, and a walk around the room's free floor looking
//! in. The dense observations are sampled on every sub-shape's surface (pipes, elbows and
//! flanges finely, equipment more coarsely, walls, floor and ceiling coarsest) and kept where
//! the frames see them, as for the pipe site ([`super::dense`]).
//!
//! No code here calls the algorithms it judges: the truth is the room's ([`PlantTruth`]).

use std::sync::Arc;

use nalgebra::{Point3, Vector3};
use parry3d_f64::math::Vector;
use parry3d_f64::query::PointQuery;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::lab::Station;
use super::plant::{Part, PlantRoom, PlantTruth};
use super::scene::{Light, Polarity, Rect, Scene, Solids};
use super::texture::Texture;
use super::truth::Orientation;

/// Target boards per wall.
const BOARDS_PER_WALL: usize = 2;
/// Board size (m): width, height.
const BOARD_SIZE: (f64, f64) = (0.9, 0.6);
/// Boards stand this far (m) in front of their wall.
const BOARD_STANDOFF_M: f64 = 0.003;
/// Radius of the boards' targets (m).
const TARGET_RADIUS_M: f64 = 0.04;
/// Closest an eye comes to any solid (m).
const EYE_CLEARANCE_M: f64 = 0.45;

/// The camera's scene of a plant room: its solids, target boards on the walls, lights.
#[must_use]
pub fn build_scene(room: &PlantRoom, seed: u64) -> Scene {
    let [length, width, height] = room.truth.room;
    let s = BOARD_STANDOFF_M;
    // (origin at the wall's left end at the floor, u along the wall, wall length); the normal
    // u × z faces into the room.
    let walls = [
        (Point3::new(s, 0.0, 0.0), Vector3::y(), width),
        (Point3::new(length - s, width, 0.0), -Vector3::y(), width),
        (Point3::new(length, s, 0.0), -Vector3::x(), length),
        (Point3::new(0.0, width - s, 0.0), Vector3::x(), length),
    ];
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0xB0A7D);
    let mut scene = Scene {
        solids: Some(Arc::new(Solids {
            compound: room.compound.clone(),
            albedo: room.reflectance.clone(),
        })),
        lights: [0.3, 0.7]
            .iter()
            .flat_map(|fx| {
                [0.3, 0.7].map(|fy| Light {
                    position: Point3::new(fx * length, fy * width, height - 0.3),
                    intensity: 4.0,
                })
            })
            .collect(),
        ambient: 0.3,
        ..Default::default()
    };
    for (w, (origin, u, wall_length)) in walls.iter().enumerate() {
        for k in 0..BOARDS_PER_WALL {
            // Boards at a third and two thirds of the wall, jittered, 1.0–1.2 m up.
            let along = wall_length * (k as f64 + 1.0) / (BOARDS_PER_WALL as f64 + 1.0)
                + rng.random_range(-0.3..0.3)
                - 0.5 * BOARD_SIZE.0;
            let up = rng.random_range(1.0..1.2);
            let rect = scene.rects.len();
            scene.rects.push(Rect::new(
                &format!("board-{}-{}", w + 1, k + 1),
                origin + u * along + Vector3::z() * up,
                *u,
                Vector3::z(),
                BOARD_SIZE,
                Texture::constant(0.75),
            ));
            // Four targets in a 2 × 2 layout, alternating polarity.
            let placed = (0..4)
                .map(|t| {
                    let a = BOARD_SIZE.0 * if t % 2 == 0 { 0.27 } else { 0.73 };
                    let b = BOARD_SIZE.1 * if t < 2 { 0.3 } else { 0.7 };
                    let polarity = if (t + k) % 3 == 0 {
                        Polarity::WhiteOnBlack
                    } else {
                        Polarity::BlackOnWhite
                    };
                    (a, b, TARGET_RADIUS_M, 1.4 * TARGET_RADIUS_M, polarity)
                })
                .collect();
            scene.place_targets(rect, placed);
        }
    }
    scene
}

/// The reference irradiance for the exposure: the brightest target centre (none saturates).
#[must_use]
pub fn reference_irradiance(scene: &Scene) -> f64 {
    scene
        .targets
        .iter()
        .map(|t| scene.irradiance(&Point3::from(t.centre), &Vector3::from(t.normal)))
        .fold(0.0, f64::max)
}

/// The distance (m) from `p` to the room's nearest solid.
fn clearance(room: &PlantRoom, p: &Point3<f64>) -> f64 {
    room.compound
        .distance_to_local_point(Vector::new(p.x, p.y, p.z), true)
}

/// The camera path: `frames` stations on a loop 1 m inside the walls (pushed toward the
/// room's centre where equipment stands closer than 0.45 m), looking into the
/// room: alternately toward the centre and 35° to either side, up and down between 0.9 and
/// 2.3 m, in landscape with a hand's roll.
#[must_use]
pub fn path(room: &PlantRoom, frames: usize, seed: u64) -> Vec<Station> {
    let [length, width, _] = room.truth.room;
    let centre = Point3::new(0.5 * length, 0.5 * width, 1.5);
    let (hx, hy) = (0.5 * length - 1.0, 0.5 * width - 1.0);
    let perimeter = 4.0 * (hx + hy);
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x9A7);
    (0..frames)
        .map(|k| {
            // Walk the rectangle's perimeter at even steps.
            let s = perimeter * k as f64 / frames as f64;
            let (x, y) = if s < 2.0 * hx {
                (-hx + s, -hy)
            } else if s < 2.0 * (hx + hy) {
                (hx, -hy + (s - 2.0 * hx))
            } else if s < 4.0 * hx + 2.0 * hy {
                (hx - (s - 2.0 * (hx + hy)), hy)
            } else {
                (-hx, hy - (s - 4.0 * hx - 2.0 * hy))
            };
            let height = 1.5 + 0.15 * (k as f64 * 0.7).sin();
            let mut eye = centre + Vector3::new(x, y, height - 1.5);
            let inward = (centre - eye).xy().normalize();
            while clearance(room, &eye) < EYE_CLEARANCE_M
                && (eye - centre).xy().norm() > EYE_CLEARANCE_M
            {
                eye += Vector3::new(inward.x, inward.y, 0.0) * 0.05;
            }
            let yaw = [0.0, 35f64.to_radians(), -35f64.to_radians()][k % 3];
            let (sin, cos) = yaw.sin_cos();
            let look = Vector3::new(
                cos * inward.x - sin * inward.y,
                sin * inward.x + cos * inward.y,
                0.0,
            );
            let aim = eye
                + look * 3.0
                + Vector3::z()
                    * ([0.9, 2.3, 1.6][(k / 3) % 3] - eye.z + rng.random_range(-0.1..0.1));
            Station::held(
                &eye,
                &aim,
                Orientation::Landscape,
                rng.random_range(-2f64..2.0).to_radians(),
            )
        })
        .collect()
}

/// Dense-sample labels: [`surface_samples`]'s `label` indexes this list.
#[must_use]
pub fn labels(truth: &PlantTruth) -> Vec<String> {
    let mut labels = vec!["equipment".to_string(), "room".to_string()];
    labels.extend(truth.segments.iter().map(|s| format!("segment {}", s.id)));
    labels
}

/// Points on every sub-shape's surface with their outward normals and labels ([`labels`]):
/// pipe segments, elbows and flanges every `pipe_spacing` (m), everything else (walls, floor,
/// ceiling, equipment) every `surface_spacing`, as the pipe site samples its wall and floor. Points inside another
/// shape are left to the visibility test of whoever observes them.
#[must_use]
pub fn surface_samples(
    room: &PlantRoom,
    pipe_spacing: f64,
    surface_spacing: f64,
) -> Vec<super::dense::Sample> {
    let mut out = Vec::new();
    for (k, (pose, shape)) in room.compound.shapes().iter().enumerate() {
        let (spacing, label) = match room.parts.get(k) {
            Some(Part::Segment(id)) => (pipe_spacing, u8::try_from(2 + id).unwrap_or(u8::MAX)),
            Some(Part::Object(id)) => match room.truth.objects[*id].kind.as_str() {
                "elbow" | "flange" => (pipe_spacing, 0),
                "wall" | "floor" | "ceiling" => (surface_spacing, 1),
                _ => (surface_spacing, 0),
            },
            None => continue,
        };
        let mut push = |p: Vector, n: Vector| {
            let (p, n) = (pose.transform_point(p), pose.rotation * n);
            out.push((
                Point3::new(p.x, p.y, p.z),
                Vector3::new(n.x, n.y, n.z),
                label,
            ));
        };
        if let Some(c) = shape.as_cylinder() {
            let (r, h) = (c.radius, c.half_height);
            let around = (std::f64::consts::TAU * r / spacing).ceil().max(8.0) as usize;
            let along = (2.0 * h / spacing).ceil().max(1.0) as usize;
            for i in 0..around {
                let phi = std::f64::consts::TAU * (i as f64 + 0.5) / around as f64;
                let (sin, cos) = phi.sin_cos();
                for j in 0..along {
                    let y = -h + 2.0 * h * (j as f64 + 0.5) / along as f64;
                    push(Vector::new(r * cos, y, r * sin), Vector::new(cos, 0.0, sin));
                }
            }
            let n = (2.0 * r / spacing).ceil() as usize;
            for side in [-1.0, 1.0] {
                for i in 0..n {
                    for j in 0..n {
                        let x = -r + 2.0 * r * (i as f64 + 0.5) / n as f64;
                        let z = -r + 2.0 * r * (j as f64 + 0.5) / n as f64;
                        if x * x + z * z <= r * r {
                            push(Vector::new(x, side * h, z), Vector::new(0.0, side, 0.0));
                        }
                    }
                }
            }
        } else if let Some(b) = shape.as_cuboid() {
            let e = b.half_extents;
            for axis in 0..3 {
                let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
                let (nu, nv) = (
                    (2.0 * e[u] / spacing).ceil().max(1.0) as usize,
                    (2.0 * e[v] / spacing).ceil().max(1.0) as usize,
                );
                for side in [-1.0, 1.0] {
                    for i in 0..nu {
                        for j in 0..nv {
                            let mut p = [0.0; 3];
                            p[axis] = side * e[axis];
                            p[u] = -e[u] + 2.0 * e[u] * (i as f64 + 0.5) / nu as f64;
                            p[v] = -e[v] + 2.0 * e[v] * (j as f64 + 0.5) / nv as f64;
                            let mut n = [0.0; 3];
                            n[axis] = side;
                            push(Vector::from(p), Vector::from(n));
                        }
                    }
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::pose::camera_centre;

    /// The targets sit on their boards just in front of the walls, facing into the room, and a
    /// ray from the room to a target's centre hits it (the board, not the wall behind).
    #[test]
    fn the_targets_face_into_the_room_on_their_boards() {
        let room = super::super::plant::plant_room(2);
        let scene = build_scene(&room, 2);
        let [l, w, _] = room.truth.room;
        assert_eq!(scene.targets.len(), 4 * BOARDS_PER_WALL * 4);
        let centre = Point3::new(0.5 * l, 0.5 * w, 1.5);
        for t in &scene.targets {
            let c = Point3::from(t.centre);
            let n = Vector3::from(t.normal);
            assert!(n.dot(&(centre - c)) > 0.0, "{t:?} faces away");
            let wall = c.x.min(l - c.x).min(c.y).min(w - c.y);
            assert!((wall - BOARD_STANDOFF_M).abs() < 1e-9, "{t:?}: {wall}");
            // From 2 cm in front of the target, straight at it: its disc, not the wall.
            let eye = c + n * 0.02;
            let hit = scene.intersect(&eye, &(c - eye)).unwrap();
            assert!((hit.t - 1.0).abs() < 1e-9, "{}", hit.t);
            assert!(hit.region & 0xff0 != 0, "not a target: {hit:?}");
        }
    }

    /// Every eye stands clear of the equipment, inside the room, and looks into it.
    #[test]
    fn the_path_stands_clear_and_looks_in() {
        for seed in 1..4 {
            let room = super::super::plant::plant_room(seed);
            let [l, w, h] = room.truth.room;
            for s in path(&room, 60, seed) {
                let eye = camera_centre(&s.cam_from_world);
                assert!(eye.x > 0.5 && eye.x < l - 0.5 && eye.y > 0.5 && eye.y < w - 0.5);
                assert!(eye.z > 1.0 && eye.z < h);
                assert!(clearance(&room, &eye) >= EYE_CLEARANCE_M - 1e-9, "{eye:?}");
            }
        }
    }

    /// A pipe segment's samples lie on its surface (at its radius from its axis) with radial
    /// normals.
    #[test]
    fn segment_samples_lie_on_the_segment() {
        let room = super::super::plant::plant_room(1);
        let samples = surface_samples(&room, 0.01, 0.05);
        let seg = &room.truth.segments[0];
        let (a, b) = (Vector3::from(seg.start), Vector3::from(seg.end));
        let d = (b - a).normalize();
        let mut lateral = 0;
        for (p, n, label) in samples.iter().filter(|s| s.2 == 2) {
            assert_eq!(*label, 2);
            let w = p.coords - a;
            let radial = w - d * w.dot(&d);
            if n.dot(&d).abs() < 1e-9 {
                assert!((radial.norm() - seg.outside_radius_m).abs() < 1e-9);
                assert!((radial.normalize() - n).norm() < 1e-9);
                lateral += 1;
            }
        }
        let expected = (seg.length() / 0.01).ceil()
            * (std::f64::consts::TAU * seg.outside_radius_m / 0.01)
                .ceil()
                .max(8.0);
        assert_eq!(lateral as f64, expected);
    }
}
