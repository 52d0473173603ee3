//! Geometry value types and small exact computations shared by every stage (layer 1).
//!
//! Poses follow COLMAP's `cam_from_world` naming: see the crate's `# Conventions`.

pub mod pose;

pub use pose::Rigid3;
