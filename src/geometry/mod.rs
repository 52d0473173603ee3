//! Geometry value types and small exact computations shared by every stage (layer 1): poses,
//! conics and ellipses, triangulation.
//!
//! Poses follow COLMAP's `cam_from_world` naming: see the crate's `# Conventions`.

pub mod conic;
pub mod eccentricity;
pub mod epipolar;
pub mod pose;
pub mod quan;
pub mod triangulation;

pub use conic::Ellipse;
pub use pose::Rigid3;
