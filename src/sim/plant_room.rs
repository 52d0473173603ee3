//! A simulated plant room's parts and their truth: the nominal pipe sizes it draws from,
//! each straight segment's and object's truth, and the room itself (a parry3d compound with
//! what each sub-shape is). [`super::plant`] and [`super::plant_process`] build rooms through
//! a shared builder; the scanner in [`super::plant`] reads them.

use nalgebra::Vector3;
use parry3d_f64::shape::Compound;
use serde::Serialize;

/// ASME B36.10M / B36.19M nominal pipe sizes used by the simulator: (NPS, DN, outside
/// diameter in mm).
pub const SIM_PIPE_SIZES: [(&str, u32, f64); 6] = [
    ("2", 50, 60.3),
    ("3", 80, 88.9),
    ("4", 100, 114.3),
    ("5", 125, 141.3),
    ("6", 150, 168.3),
    ("8", 200, 219.1),
];

/// The pipe materials the simulator draws (both on ASME outside diameters).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Material {
    /// Carbon steel (ASME B36.10M).
    Steel,
    /// Stainless steel (ASME B36.19M, the same outside diameters).
    Stainless,
}

/// One straight pipe segment of the truth.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PipeSegmentTruth {
    /// Index in the truth's list.
    pub id: usize,
    /// The run it belongs to (`riser`, `header`, `branch`, `small-bore`).
    pub run: String,
    /// Axis start (m).
    pub start: [f64; 3],
    /// Axis end (m).
    pub end: [f64; 3],
    /// Outside radius (m).
    pub outside_radius_m: f64,
    /// Nominal pipe size (`"4"` for NPS 4).
    pub nps: String,
    /// The same as DN.
    pub dn: u32,
    /// Material.
    pub material: Material,
}

impl PipeSegmentTruth {
    /// Length of the axis (m).
    #[must_use]
    pub fn length(&self) -> f64 {
        (Vector3::from(self.end) - Vector3::from(self.start)).norm()
    }
}

/// One object of the room that is not a straight pipe segment.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ObjectTruth {
    /// Index in the truth's list.
    pub id: usize,
    /// What it is: `wall`, `floor`, `ceiling`, `column`, `elbow`, `flange`, `valve`, `support`,
    /// `housing`, `motor`, `plinth`, `conduit`.
    pub kind: String,
    /// Axis-aligned bounds (m): min and max corner.
    pub bounds: [[f64; 3]; 2],
}

/// The scan's settings, as recorded in the truth.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ScanTruth {
    /// Scanner stations (m).
    pub stations: Vec<[f64; 3]>,
    /// Angular step (rad).
    pub step_rad: f64,
    /// Range noise σ (m).
    pub range_noise_m: f64,
    /// Points written.
    pub points: usize,
    /// Of them, mixed pixels (ranges blended across a depth edge).
    pub mixed_pixels: usize,
}

/// The truth of a plant room: `truth.json` of `pipemeasure simulate plant`.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PlantTruth {
    /// `pipemeasure.plant-truth/1`.
    pub schema: &'static str,
    /// The seed the room was drawn with.
    pub seed: u64,
    /// Room size (m): length along x, width along y, height.
    pub room: [f64; 3],
    /// Every straight pipe segment.
    pub segments: Vec<PipeSegmentTruth>,
    /// Every other object.
    pub objects: Vec<ObjectTruth>,
    /// The scan, once made.
    pub scan: Option<ScanTruth>,
}

/// What a sub-shape of the room belongs to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Part {
    /// A pipe segment of the truth.
    Segment(usize),
    /// An object of the truth.
    Object(usize),
}

/// A plant room: its parry3d compound (one bounding-volume hierarchy over every part), what
/// each sub-shape is, each sub-shape's reflectance, and the truth.
pub struct PlantRoom {
    /// Every shape of the room.
    pub compound: Compound,
    /// Per sub-shape of [`Self::compound`], its part of the truth.
    pub parts: Vec<Part>,
    /// Per sub-shape, its reflectance in (0, 1] (the scan's intensity).
    pub reflectance: Vec<f64>,
    /// The truth.
    pub truth: PlantTruth,
}
