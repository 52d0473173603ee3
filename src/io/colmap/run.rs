//! Running the real COLMAP (3.8, CPU only) for structure from motion: `feature_extractor`
//! (one shared SIMPLE_RADIAL camera), `sequential_matcher` (video frames), `mapper`; the
//! largest resulting model is read back.

use std::path::{Path, PathBuf};
use std::process::Command;

use super::{ModelFormat, Reconstruction};
use crate::io::error::ReadError;

/// Why running COLMAP failed.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ColmapRunError {
    /// `colmap` is not on PATH.
    #[error(
        "`colmap` is not installed or not on PATH (Debian/Ubuntu: `apt-get install -y colmap`); or pass an existing sparse model"
    )]
    NotInstalled,
    /// A COLMAP step exited with an error.
    #[error("colmap {step} failed ({status}):\n{stderr}")]
    Failed {
        /// The step (`feature_extractor`, ...).
        step: &'static str,
        /// Exit status.
        status: String,
        /// The end of its output.
        stderr: String,
    },
    /// The mapper produced no model.
    #[error("colmap mapper reconstructed nothing in {}: the frames may lack texture or overlap", .0.display())]
    NoModel(PathBuf),
    /// The work folder could not be prepared.
    #[error("preparing {}: {source}", .path.display())]
    Io {
        /// The path.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// The model could not be read.
    #[error(transparent)]
    Read(#[from] ReadError),
}

/// Whether `colmap` can be run.
#[must_use]
pub fn colmap_available() -> bool {
    Command::new("colmap")
        .arg("help")
        .output()
        .is_ok_and(|o| o.status.success())
}

fn step(name: &'static str, args: &[&str]) -> Result<(), ColmapRunError> {
    let out = Command::new("colmap")
        .arg(name)
        .args(args)
        .env("QT_QPA_PLATFORM", "offscreen")
        .output()
        .map_err(|_| ColmapRunError::NotInstalled)?;
    if out.status.success() {
        return Ok(());
    }
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let tail: Vec<&str> = text.lines().rev().take(15).collect();
    Err(ColmapRunError::Failed {
        step: name,
        status: out.status.to_string(),
        stderr: tail.into_iter().rev().collect::<Vec<_>>().join("\n"),
    })
}

/// Runs COLMAP's sparse reconstruction on the frames in `images` with `work` as its workspace
/// (created; an existing `database.db` there is replaced) and returns the model with the most
/// registered images.
///
/// # Errors
///
/// [`ColmapRunError`].
pub fn run_colmap_sfm(images: &Path, work: &Path) -> Result<Reconstruction, ColmapRunError> {
    if !colmap_available() {
        return Err(ColmapRunError::NotInstalled);
    }
    let sparse = work.join("sparse");
    std::fs::create_dir_all(&sparse).map_err(|e| ColmapRunError::Io {
        path: sparse.clone(),
        source: e,
    })?;
    let db = work.join("database.db");
    if db.exists() {
        std::fs::remove_file(&db).map_err(|e| ColmapRunError::Io {
            path: db.clone(),
            source: e,
        })?;
    }
    let s = |p: &Path| p.to_string_lossy().into_owned();
    let (db_s, images_s, sparse_s) = (s(&db), s(images), s(&sparse));
    step(
        "feature_extractor",
        &[
            "--database_path",
            &db_s,
            "--image_path",
            &images_s,
            "--ImageReader.single_camera",
            "1",
            "--ImageReader.camera_model",
            "SIMPLE_RADIAL",
            "--SiftExtraction.use_gpu",
            "0",
        ],
    )?;
    step(
        "sequential_matcher",
        &["--database_path", &db_s, "--SiftMatching.use_gpu", "0"],
    )?;
    step(
        "mapper",
        &[
            "--database_path",
            &db_s,
            "--image_path",
            &images_s,
            "--output_path",
            &sparse_s,
        ],
    )?;
    let mut best: Option<Reconstruction> = None;
    let entries = std::fs::read_dir(&sparse).map_err(|e| ColmapRunError::Io {
        path: sparse.clone(),
        source: e,
    })?;
    let mut dirs: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.is_dir())
        .collect();
    dirs.sort();
    for dir in dirs {
        let model = Reconstruction::read_format(&dir, ModelFormat::Binary)?;
        if best
            .as_ref()
            .is_none_or(|b| model.images.len() > b.images.len())
        {
            best = Some(model);
        }
    }
    best.ok_or(ColmapRunError::NoModel(sparse))
}
