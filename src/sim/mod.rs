//! The simulator (layer 5): the paper's calibration lab and pipe site with exact ground truth.
//! It may use value types, I/O and profiles, never the algorithms it judges (`detect`,
//! `robust`, `calibrate`, `adjust`, `measure`), so that its truth stays independent.

pub mod bundle;
pub mod dense;
pub mod devices;
pub mod lab;
pub mod render;
pub mod scene;
pub mod sfm;
pub mod simulate;
pub mod site;
pub mod texture;
pub mod truth;
