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

/// COLMAP's options for the frames of a video. The SfM model only
/// starts the calibration (Algorithm 1's poses and feature tracks); the targets' own
/// adjustment gives the camera, so the features need not be extracted at the full 4K size.
///
/// Measured on the simulated 90-frame 4K video lab (P30, 2026-12-05; `README.md`, "Frame
/// choice from video"): at COLMAP's default 3200 px the extraction took 261 of 358 s; at
/// 1920 px it took 95 of 206 s, with all 90 frames registered either way and calibrations
/// 0.002 px apart.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ColmapOptions {
    /// `SiftExtraction.max_image_size`: the longest side (px) the features are extracted at;
    /// larger frames are downsized for it (COLMAP's default: 3200).
    pub max_image_size: u32,
    /// `SiftExtraction.max_num_features` per frame (COLMAP's default, 8192: a lab's frames
    /// give 400–1400 features at 1920 px, so it does not bind there).
    pub max_num_features: u32,
    /// `SequentialMatching.overlap`: each frame is matched with the next this many (COLMAP's
    /// default, 10: ten seconds of a 1 fps extraction; the matching took 36 of 206 s).
    pub overlap: u32,
}

impl ColmapOptions {
    /// The options for `feature_extractor`.
    #[must_use]
    pub fn extractor_args(&self) -> [String; 4] {
        [
            "--SiftExtraction.max_image_size".into(),
            self.max_image_size.to_string(),
            "--SiftExtraction.max_num_features".into(),
            self.max_num_features.to_string(),
        ]
    }

    /// The options for `sequential_matcher`.
    #[must_use]
    pub fn matcher_args(&self) -> [String; 2] {
        [
            "--SequentialMatching.overlap".into(),
            self.overlap.to_string(),
        ]
    }
}

impl Default for ColmapOptions {
    fn default() -> Self {
        ColmapOptions {
            max_image_size: 1920,
            max_num_features: 8192,
            overlap: 10,
        }
    }
}

/// Whether `colmap` can be run.
#[must_use]
pub fn colmap_available() -> bool {
    crate::io::tools::probe(crate::io::tools::Tool::Colmap).found()
}

/// Where a COLMAP run is, read from its own log (COLMAP 3.8's messages).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum ColmapProgress {
    /// `feature_extractor`: "Processed file [i/n]".
    Features {
        /// Images done.
        done: usize,
        /// Images in all.
        of: usize,
    },
    /// `sequential_matcher`: "Matching image [i/n]".
    Matching {
        /// Images matched.
        done: usize,
        /// Images in all.
        of: usize,
    },
    /// `mapper`: "Initializing with image pair" (2), then "Registering image #id (k)".
    Registered {
        /// Images registered in the current model.
        images: usize,
    },
}

/// Parses one line of COLMAP's log into progress.
#[must_use]
pub fn parse_progress(line: &str) -> Option<ColmapProgress> {
    let line = line.trim();
    let counts = |rest: &str| -> Option<(usize, usize)> {
        let inner = rest.strip_prefix('[')?.split(']').next()?;
        let (done, of) = inner.split_once('/')?;
        Some((done.trim().parse().ok()?, of.trim().parse().ok()?))
    };
    if let Some(rest) = line.strip_prefix("Processed file ") {
        let (done, of) = counts(rest)?;
        return Some(ColmapProgress::Features { done, of });
    }
    if let Some(rest) = line.strip_prefix("Matching image ") {
        let (done, of) = counts(rest)?;
        return Some(ColmapProgress::Matching { done, of });
    }
    if line.starts_with("Initializing with image pair") {
        return Some(ColmapProgress::Registered { images: 2 });
    }
    if let Some(rest) = line.strip_prefix("Registering image #") {
        let k = rest.split_once('(')?.1.strip_suffix(')')?;
        return Some(ColmapProgress::Registered {
            images: k.trim().parse().ok()?,
        });
    }
    None
}

/// Runs one COLMAP step, reporting the progress its log shows.
fn step(
    name: &'static str,
    args: &[&str],
    progress: &dyn Fn(ColmapProgress),
) -> Result<(), ColmapRunError> {
    use std::io::BufRead;
    let mut child = Command::new("colmap")
        .arg(name)
        .args(args)
        .env("QT_QPA_PLATFORM", "offscreen")
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .map_err(|_| ColmapRunError::NotInstalled)?;
    // Both streams are read on their own threads (a full pipe would stall COLMAP); their lines
    // come here in the order read.
    let (tx, rx) = std::sync::mpsc::channel::<String>();
    let readers: Vec<_> = [
        child
            .stdout
            .take()
            .map(|s| Box::new(s) as Box<dyn std::io::Read + Send>),
        child
            .stderr
            .take()
            .map(|s| Box::new(s) as Box<dyn std::io::Read + Send>),
    ]
    .into_iter()
    .flatten()
    .map(|stream| {
        let tx = tx.clone();
        std::thread::spawn(move || {
            for line in std::io::BufReader::new(stream)
                .lines()
                .map_while(Result::ok)
            {
                if tx.send(line).is_err() {
                    break;
                }
            }
        })
    })
    .collect();
    drop(tx);
    let mut tail: std::collections::VecDeque<String> = std::collections::VecDeque::new();
    for line in rx {
        if let Some(p) = parse_progress(&line) {
            progress(p);
        }
        if tail.len() == 15 {
            tail.pop_front();
        }
        tail.push_back(line);
    }
    for r in readers {
        let _ = r.join();
    }
    let status = child.wait().map_err(|e| ColmapRunError::Failed {
        step: name,
        status: "wait".into(),
        stderr: e.to_string(),
    })?;
    if status.success() {
        return Ok(());
    }
    Err(ColmapRunError::Failed {
        step: name,
        status: status.to_string(),
        stderr: tail.into_iter().collect::<Vec<_>>().join("\n"),
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
    run_colmap_sfm_with(images, work, None, &ColmapOptions::default(), &|_| {})
}

/// [`run_colmap_sfm`] on the images named in `image_list` only (relative to `images`; all
/// images under it, recursively, when `None`: COLMAP reads subfolders, so a video's
/// neighbour frames must be left out this way), reporting progress from COLMAP's log.
///
/// # Errors
///
/// [`ColmapRunError`].
pub fn run_colmap_sfm_with(
    images: &Path,
    work: &Path,
    image_list: Option<&[String]>,
    options: &ColmapOptions,
    progress: &dyn Fn(ColmapProgress),
) -> Result<Reconstruction, ColmapRunError> {
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
    let list_path = work.join("image_list.txt");
    let list_s = s(&list_path);
    let (extractor_args, matcher_args) = (options.extractor_args(), options.matcher_args());
    let mut extract = vec![
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
    ];
    extract.extend(extractor_args.iter().map(String::as_str));
    if let Some(list) = image_list {
        let mut text = list.join("\n");
        text.push('\n');
        std::fs::write(&list_path, text).map_err(|e| ColmapRunError::Io {
            path: list_path.clone(),
            source: e,
        })?;
        extract.extend(["--image_list_path", &list_s]);
    }
    step("feature_extractor", &extract, progress)?;
    let mut matcher = vec!["--database_path", &db_s, "--SiftMatching.use_gpu", "0"];
    matcher.extend(matcher_args.iter().map(String::as_str));
    step("sequential_matcher", &matcher, progress)?;
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
        progress,
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn colmap_log_lines_give_progress() {
        assert_eq!(
            parse_progress("Processed file [3/42]"),
            Some(ColmapProgress::Features { done: 3, of: 42 })
        );
        assert_eq!(
            parse_progress("Matching image [12/42] in 0.244s"),
            Some(ColmapProgress::Matching { done: 12, of: 42 })
        );
        assert_eq!(
            parse_progress("Initializing with image pair #1 and #3"),
            Some(ColmapProgress::Registered { images: 2 })
        );
        assert_eq!(
            parse_progress("Registering image #17 (9)"),
            Some(ColmapProgress::Registered { images: 9 })
        );
        assert_eq!(parse_progress("  => Image sees 31 / 273 points"), None);
        assert_eq!(parse_progress("Processed file [x/42]"), None);
    }

    /// COLMAP 3.8 knows every option we pass (a misspelt one makes it exit with an error):
    /// each is listed in the step's own help.
    #[test]
    fn colmap_knows_the_options_passed() {
        if !colmap_available() {
            eprintln!("skipped: colmap is not installed");
            return;
        }
        let help = |step: &str| {
            let out = Command::new("colmap")
                .args([step, "-h"])
                .env("QT_QPA_PLATFORM", "offscreen")
                .output()
                .unwrap();
            String::from_utf8_lossy(&out.stdout).into_owned()
                + &String::from_utf8_lossy(&out.stderr)
        };
        let options = ColmapOptions::default();
        for (step, args) in [
            ("feature_extractor", options.extractor_args().to_vec()),
            ("sequential_matcher", options.matcher_args().to_vec()),
        ] {
            let text = help(step);
            for name in args.iter().step_by(2) {
                assert!(
                    text.contains(&format!("{name} arg")),
                    "colmap {step} -h does not list {name}"
                );
            }
        }
    }
}
