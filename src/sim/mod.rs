//! The simulator (layer 5): scenes with exact ground truth. It may use value types, I/O and
//! profiles, never the algorithms it judges (`detect`, `robust`, `calibrate`, `adjust`,
//! `measure`), so that its truth stays independent.

pub mod devices;
