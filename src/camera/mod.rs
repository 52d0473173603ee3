//! Camera models (layer 1): the `brown` model with its Jacobians, conversions to and from COLMAP
//! and OpenCV cameras, and undistortion maps for whole frames.

pub mod brown;
pub mod convert;
pub mod rolling;
pub mod undistort_map;

pub use brown::{BrownCamera, Intrinsics, Projection, Term, UndistortError, WorldProjection};
