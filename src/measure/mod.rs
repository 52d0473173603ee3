//! The measurement job (layer 4): the cloud around a local origin with its normals (`cloud`),
//! its points in Z-order with the implicit octree and uniform grids that order gives (`zorder`:
//! the exact nearest neighbours of scattered points and of a band of points), robust cylinder
//! fitting (`cylinder`), the site's targets (`targets`), the scale from them against the TLS
//! (`scale`), the pipe network (`network`), which pipe the user filmed (`choice`), and the
//! pipes measured in metres with their reference (`pipe`).

pub mod choice;
pub mod cloud;
pub mod cylinder;
pub mod network;
pub mod nominal;
pub mod pipe;
pub mod scale;
pub mod scan;
pub mod shell;
pub mod site;
pub mod targets;
mod zorder;

pub use choice::{Choice, ChosenBy, View, pipe_of_interest};
pub use cloud::{Cloud, CloudError};
pub use cylinder::{
    Cylinder, CylinderConfig, CylinderError, CylinderFit, fit_all_cylinders, fit_cylinder,
    fit_cylinder_among, refit_among,
};
pub use network::{Network, NetworkConfig, NetworkError, PipeSegment, extract_network};
pub use nominal::{NominalSize, PipeMaterial, nominal_size};
pub use pipe::{
    PipeMeasurement, Reference, Region, Scaling, fit_points, measure_pipe, reference_fit,
    transformed_points,
};
pub use scale::{ReconstructedTarget, ScaleConfig, ScaleError, ScaleEstimate, estimate_scale};
pub use targets::{SiteTargets, match_site_targets};
