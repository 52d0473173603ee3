//! Building a plant room: parry3d shapes collected with what each is in the truth (a straight
//! pipe segment or another object) and its reflectance, and the pipe sizes the rooms draw.

use nalgebra::Vector3;
use parry3d_f64::math::{Pose, Vector};
use parry3d_f64::shape::{Compound, Cuboid, SharedShape};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::plant_room::{
    Material, ObjectTruth, Part, PipeSegmentTruth, PlantRoom, PlantTruth, SIM_PIPE_SIZES,
};
use crate::geometry::solid;

fn v(p: [f64; 3]) -> Vector {
    Vector::new(p[0], p[1], p[2])
}

/// The pose of a parry cylinder (axis along local y) from `a` to `b`.
pub(super) fn cylinder_between(a: [f64; 3], b: [f64; 3], radius: f64) -> (Pose, SharedShape) {
    let (pose, solid) = solid::cylinder_between(&a.into(), &b.into(), radius);
    (pose, SharedShape::new(solid))
}

/// An axis-aligned box from its corners.
pub(super) fn cuboid(min: [f64; 3], max: [f64; 3]) -> (Pose, SharedShape) {
    let (lo, hi) = (v(min), v(max));
    (
        Pose::from_translation((lo + hi) * 0.5),
        SharedShape::new(Cuboid::new((hi - lo) * 0.5)),
    )
}

/// Collects the room's shapes and their truth as it is built.
pub(super) struct Builder {
    pub(super) shapes: Vec<(Pose, SharedShape)>,
    pub(super) parts: Vec<Part>,
    pub(super) reflectance: Vec<f64>,
    pub(super) segments: Vec<PipeSegmentTruth>,
    pub(super) objects: Vec<ObjectTruth>,
}

impl Builder {
    /// An empty room.
    pub(super) fn new() -> Self {
        Builder {
            shapes: Vec::new(),
            parts: Vec::new(),
            reflectance: Vec::new(),
            segments: Vec::new(),
            objects: Vec::new(),
        }
    }

    /// Walls, floor and ceiling of a room `length × width × height` (slabs outside its volume).
    pub(super) fn enclosure(&mut self, length: f64, width: f64, height: f64) {
        let t = 0.2;
        self.add_box("floor", [-t, -t, -t], [length + t, width + t, 0.0], 0.3);
        self.add_box(
            "ceiling",
            [-t, -t, height],
            [length + t, width + t, height + t],
            0.6,
        );
        self.add_box("wall", [-t, 0.0, 0.0], [0.0, width, height], 0.55);
        self.add_box(
            "wall",
            [length, 0.0, 0.0],
            [length + t, width, height],
            0.55,
        );
        self.add_box("wall", [0.0, -t, 0.0], [length, 0.0, height], 0.55);
        self.add_box("wall", [0.0, width, 0.0], [length, width + t, height], 0.55);
    }

    /// The room: its compound and truth.
    pub(super) fn finish(self, seed: u64, room: [f64; 3]) -> PlantRoom {
        PlantRoom {
            compound: Compound::new(self.shapes),
            parts: self.parts,
            reflectance: self.reflectance,
            truth: PlantTruth {
                schema: "pipemeasure.plant-truth/1",
                seed,
                room,
                segments: self.segments,
                objects: self.objects,
                scan: None,
            },
        }
    }

    pub(super) fn object(&mut self, kind: &str, bounds: [[f64; 3]; 2]) -> usize {
        let id = self.objects.len();
        self.objects.push(ObjectTruth {
            id,
            kind: kind.to_string(),
            bounds,
        });
        id
    }

    pub(super) fn add(&mut self, shape: (Pose, SharedShape), part: Part, reflectance: f64) {
        self.shapes.push(shape);
        self.parts.push(part);
        self.reflectance.push(reflectance);
    }

    pub(super) fn add_box(&mut self, kind: &str, min: [f64; 3], max: [f64; 3], reflectance: f64) {
        let id = self.object(kind, [min, max]);
        self.add(cuboid(min, max), Part::Object(id), reflectance);
    }

    /// A cylinder object (flange, conduit, housing) from `a` to `b`.
    pub(super) fn add_round(
        &mut self,
        kind: &str,
        a: [f64; 3],
        b: [f64; 3],
        radius: f64,
        refl: f64,
    ) {
        let id = self.object(kind, round_bounds(a, b, radius));
        self.add(cylinder_between(a, b, radius), Part::Object(id), refl);
    }

    /// A straight pipe segment of the truth.
    pub(super) fn add_pipe(
        &mut self,
        run: &str,
        a: [f64; 3],
        b: [f64; 3],
        size: PipeSize,
        refl: f64,
    ) {
        let id = self.segments.len();
        self.segments.push(PipeSegmentTruth {
            id,
            run: run.to_string(),
            start: a,
            end: b,
            outside_radius_m: size.radius(),
            nps: size.nps.to_string(),
            dn: size.dn,
            material: size.material,
        });
        self.add(
            cylinder_between(a, b, size.radius()),
            Part::Segment(id),
            refl,
        );
    }

    /// A 90° long-radius elbow from the tangent point `a` (leaving along `from`) to the one
    /// leaving along `to`, as 16 short cylinders along the arc: one object.
    pub(super) fn add_elbow(&mut self, a: [f64; 3], from: [f64; 3], to: [f64; 3], size: PipeSize) {
        let (a, from, to) = (Vector3::from(a), Vector3::from(from), Vector3::from(to));
        let bend = 1.5 * size.od_m();
        let centre = a + to * bend;
        let pieces = 16;
        let at = |k: usize| {
            let t = std::f64::consts::FRAC_PI_2 * k as f64 / pieces as f64;
            centre - to * bend * t.cos() + from * bend * t.sin()
        };
        let end = at(pieces);
        let mut lo = a.inf(&end).inf(&centre);
        let mut hi = a.sup(&end).sup(&centre);
        lo.add_scalar_mut(-size.radius());
        hi.add_scalar_mut(size.radius());
        let id = self.object("elbow", [lo.into(), hi.into()]);
        for k in 0..pieces {
            let (p, q) = (at(k), at(k + 1));
            // Each piece a little longer than its chord, so the extrados has no gaps.
            let d = (q - p).normalize() * size.radius() * 0.1;
            self.add(
                cylinder_between((p - d).into(), (q + d).into(), size.radius()),
                Part::Object(id),
                0.35,
            );
        }
    }
}

/// The axis-aligned bounds of a round solid of radius `r` about the axis from `a` to `b`.
pub(super) fn round_bounds(a: [f64; 3], b: [f64; 3], r: f64) -> [[f64; 3]; 2] {
    let (a, b) = (Vector3::from(a), Vector3::from(b));
    let mut lo = a.inf(&b);
    let mut hi = a.sup(&b);
    lo.add_scalar_mut(-r);
    hi.add_scalar_mut(r);
    [lo.into(), hi.into()]
}

/// A drawn pipe size and material.
#[derive(Clone, Copy, Debug)]
pub(super) struct PipeSize {
    pub(super) nps: &'static str,
    pub(super) dn: u32,
    pub(super) od_mm: f64,
    pub(super) material: Material,
}

impl PipeSize {
    pub(super) fn od_m(self) -> f64 {
        self.od_mm * 1e-3
    }
    pub(super) fn radius(self) -> f64 {
        self.od_mm * 0.5e-3
    }
}

pub(super) fn draw_size(rng: &mut ChaCha8Rng, from: usize, to: usize) -> PipeSize {
    let (nps, dn, od_mm) = SIM_PIPE_SIZES[rng.random_range(from..=to)];
    let material = if rng.random_bool(0.5) {
        Material::Steel
    } else {
        Material::Stainless
    };
    PipeSize {
        nps,
        dn,
        od_mm,
        material,
    }
}
