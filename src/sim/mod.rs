//! The simulator (layer 5): the paper's calibration lab and pipe site with exact ground truth.
//! It may use value types, I/O and profiles, never the algorithms it judges (`detect`,
//! `robust`, `calibrate`, `adjust`, `measure`), so that its truth stays independent.
//!
//! Frames are still, global-shutter photographs at the scenes' stations by default; with video
//! options ([`video`]) the stations become a continuous hand-held [`trajectory`] filmed by a
//! rolling-shutter camera with motion blur ([`shutter`], [`render::render_radiance_moving`]).
//!
//! The scenes' entry points are re-exported here: [`simulate_lab`], [`simulate_site`] and
//! [`simulate_plant`] with their settings, and the [`Truth`] they write.

pub mod bundle;
pub mod dense;
pub mod devices;
pub mod lab;
pub mod options;
pub mod plant;
mod plant_builder;
pub mod plant_process;
pub mod plant_room;
pub mod plant_site;
pub mod render;
pub mod scene;
pub mod sfm;
pub mod shutter;
pub mod simulate;
pub mod site;
pub mod texture;
pub mod trajectory;
pub mod truth;
pub mod video;
pub mod video_config;

pub use lab::{LabConfig, WallTexture};
pub use options::{SfmSource, SimError, SimulateOptions};
pub use plant::{PlantLayout, PlantScanConfig, simulate_plant};
pub use render::RenderConfig;
pub use simulate::{SiteOptions, simulate_lab, simulate_site};
pub use site::SiteConfig;
pub use truth::Truth;
pub use video_config::VideoConfig;
