//! Readers and writers for the files users bring and the files pipemeasure writes (layer 2):
//! COLMAP sparse models, BAL bundle adjustment problems, PLY and E57 clouds, frames, TLS target
//! lists; atomic writes.
//!
//! Every read error names the file and, where it has one, the line (or byte offset).

pub mod atomic;
pub mod bal;
pub mod colmap;
pub mod e57;
pub mod error;
pub mod frames;
pub mod observations;
pub mod ply;
pub mod sidecar;
pub mod tls;
pub mod tools;
pub mod vis;

pub use error::{Location, ReadError, ReadErrorKind, WriteError};
