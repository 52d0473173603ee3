//! Reports for people (layer 6): the calibration report (`report.md`, `report.json`), its plots
//! (SVG, plotters) and tables; the pipe network as tables, CSV and a coloured cloud.

pub mod calibration;
pub mod network;
pub mod plots;

/// A plot that could not be drawn or written.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReportError {
    /// Drawing failed.
    #[error("cannot draw {what}: {message}")]
    Draw {
        /// Which plot.
        what: &'static str,
        /// The backend's message.
        message: String,
    },
    /// Writing failed.
    #[error(transparent)]
    Write(#[from] crate::io::WriteError),
    /// A JSON report could not be serialised.
    #[error("cannot serialise the report: {0}")]
    Json(#[from] serde_json::Error),
}
