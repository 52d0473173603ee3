//! `pipemeasure profile show|list|export`.

use std::fmt::Write as _;

use anyhow::{Result, bail};
use pipemeasure::calibrate::checks::check_distortion;
use pipemeasure::camera::Term;
use pipemeasure::camera::convert::{
    ColmapModel, Converted, colmap_from_brown, opencv_from_brown, simplest_colmap_model,
};
use pipemeasure::io::colmap::{CameraId, camera_text_line};
use pipemeasure::profile::{HIGH_CORRELATION, Profile, list_profiles, load_located};

/// `profile` subcommands.
#[derive(Debug, clap::Subcommand)]
pub enum Command {
    /// Print a profile as a table of values ± standard deviations.
    Show {
        /// Device name or profile path.
        device: String,
        /// Print the profile JSON instead.
        #[arg(long)]
        json: bool,
    },
    /// List every profile found — in $PIPEMEASURE_CALIBRATIONS, ./calibrations/, the user's
    /// data folder and the presets built in — with its origin and file; a profile shadowed by
    /// one of the same name found first is marked.
    List,
    /// Print the camera in another tool's form.
    Export {
        /// Device name or profile path.
        device: String,
        /// Target tool.
        #[arg(long, value_enum)]
        format: Format,
        /// COLMAP model (default: the simplest that is exact, else FULL_OPENCV fitted).
        #[arg(long)]
        model: Option<String>,
    },
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum Format {
    /// A COLMAP cameras.txt.
    Colmap,
    /// An OpenCV FileStorage YAML (camera_matrix, distortion_coefficients).
    Opencv,
}

pub fn run(cmd: &Command) -> Result<()> {
    match cmd {
        Command::Show { device, json } => {
            let (located, profile) = load_located(device)?;
            let path = located.path;
            if *json {
                outln!("{}", profile.to_json());
            } else {
                out!(
                    "{}",
                    show(&profile, &format!("{}, {}", path.display(), located.origin))
                );
            }
            let size = (profile.image.width, profile.image.height);
            let check = check_distortion(&profile.intrinsics, size);
            if !check.ok {
                eprintln!(
                    "warning: {}: the distortion cannot be inverted over the frame: it folds back \
                     from {:.0} px from the principal point (the frame reaches {:.0} px); \
                     `undistort` refuses this profile",
                    path.display(),
                    check.first_failure_radius_px.unwrap_or(0.0),
                    check.frame_radius_px
                );
            }
        }
        Command::List => {
            // Always at least the presets built in.
            for l in list_profiles() {
                let shadowed = l
                    .shadowed_by
                    .map(|o| format!("\tshadowed by {o}"))
                    .unwrap_or_default();
                outln!(
                    "{}\t{}\t{}{shadowed}",
                    l.name,
                    l.located.origin,
                    l.located.path.display()
                );
            }
        }
        Command::Export {
            device,
            format,
            model,
        } => {
            let (_, profile) = load_located(device)?;
            let text = match format {
                Format::Colmap => export_colmap(&profile, model.as_deref())?,
                Format::Opencv => {
                    if model.is_some() {
                        bail!("--model applies to --format colmap only");
                    }
                    export_opencv(&profile)?
                }
            };
            out!("{text}");
        }
    }
    Ok(())
}

/// The readable table of `profile show`.
fn show(p: &Profile, path: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "device      {}  ({path})", p.device);
    let _ = writeln!(
        s,
        "image       {} x {} px, model {}",
        p.image.width, p.image.height, p.model
    );
    let terms: Vec<&str> = p.terms.iter().map(|t| t.name()).collect();
    let _ = writeln!(
        s,
        "estimated   {}",
        if terms.is_empty() {
            "none (not a calibration)".to_string()
        } else {
            terms.join(" ")
        }
    );
    let _ = writeln!(s, "\n{:<6} {:>16}   {:>12}", "term", "value", "std dev");
    for t in Term::ALL {
        let v = p.intrinsics.get(t);
        let sd = p.std_dev.get(t);
        let estimated = p.terms.contains(&t);
        if !estimated && v == 0.0 {
            continue;
        }
        let value = if t.unit() == "px" {
            format!("{v:.4} px")
        } else {
            format!("{v:.6e}")
        };
        let sd = if estimated {
            format!(
                "± {}",
                if t.unit() == "px" {
                    format!("{sd:.4}")
                } else {
                    format!("{sd:.2e}")
                }
            )
        } else {
            "fixed".into()
        };
        let _ = writeln!(s, "{:<6} {value:>16}   {sd:>12}", t.name());
    }
    let stats: Vec<String> = [
        p.residual_rms_px.map(|v| format!("residual RMS {v:.4} px")),
        p.sigma0.map(|v| format!("sigma0 {v:.3}")),
        (p.images > 0).then(|| format!("{} images", p.images)),
        (p.targets > 0).then(|| format!("{} targets", p.targets)),
        (p.observations > 0).then(|| format!("{} observations", p.observations)),
    ]
    .into_iter()
    .flatten()
    .collect();
    if !stats.is_empty() {
        let _ = writeln!(s, "\n{}", stats.join(", "));
    }
    // Row by row of the correlation matrix, as the profile lists its terms.
    let pos = |n: &str| p.correlation.names.iter().position(|t| t.name() == n);
    let mut pairs = p.high_correlations();
    pairs.sort_by_key(|(a, b, _)| (pos(a), pos(b)));
    let high: Vec<String> = pairs
        .iter()
        .map(|(a, b, r)| format!("{a}–{b} {r:+.3}"))
        .collect();
    if !p.correlation.names.is_empty() {
        let _ = writeln!(
            s,
            "correlations above {HIGH_CORRELATION}: {}",
            if high.is_empty() {
                "none".into()
            } else {
                high.join(", ")
            }
        );
    }
    let _ = writeln!(s, "\n{}", rolling_shutter_line(p));
    let checks = checks_lines(p);
    if !checks.is_empty() {
        let _ = writeln!(s, "checks");
        for c in checks {
            let _ = writeln!(s, "  {c}");
        }
    }
    if !p.provenance.is_empty() {
        let _ = writeln!(s, "\nprovenance");
        for (k, v) in &p.provenance {
            let v = v.as_str().map_or_else(|| v.to_string(), str::to_string);
            let _ = writeln!(s, "  {k}: {v}");
        }
    }
    s
}

/// The rolling shutter as the profile holds it: the readout time ± σ, whether it was
/// estimated or given, and the order of the frames' motions.
fn rolling_shutter_line(p: &Profile) -> String {
    let Some(r) = &p.rolling_shutter else {
        return "rolling shutter  not modelled (no readout time: measured as a global shutter unless --readout-time is given)".into();
    };
    let order = p
        .motion_order()
        .map_or_else(String::new, |o| format!("; frames' motions of order {o}"));
    if r.estimated {
        format!(
            "rolling shutter  readout {:.3} ± {:.3} ms, estimated from the frames' video neighbours{order}",
            r.readout_s * 1e3,
            r.readout_std_s * 1e3
        )
    } else {
        format!(
            "rolling shutter  readout {:.3} ms, given (held in the calibration){order}",
            r.readout_s * 1e3
        )
    }
}

/// The checks the calibration ran, as the profile records them: the jackknife over the frames
/// and the cross-validation of two halves.
fn checks_lines(p: &Profile) -> Vec<String> {
    let mut out = Vec::new();
    if let Some(j) = p.jackknife() {
        out.push(format!(
            "jackknife over {:.0} groups of frames: covariance × {:.3} (σ × {:.3})",
            j.groups,
            j.variance_inflation,
            j.variance_inflation.sqrt()
        ));
    }
    if let Some(c) = p.cross_validation() {
        out.push(format!(
            "cross-validation: the halves' projections {:.4} px RMS apart, {:.2} × what their σ predict",
            c.rms_px, c.ratio
        ));
    }
    out
}

fn conversion_note<T>(c: &Converted<T>) -> String {
    if c.exact {
        format!(
            "exact conversion (max difference {:.1e} px over the image)",
            c.max_error_px
        )
    } else {
        format!(
            "least-squares fit: this model lacks {}; max error {:.4} px, RMS {:.4} px over the image",
            c.missing_terms.join(", "),
            c.max_error_px,
            c.rms_error_px
        )
    }
}

fn export_colmap(p: &Profile, model: Option<&str>) -> Result<String> {
    let cam = p.camera();
    let model = match model {
        Some(name) => match ColmapModel::from_name(&name.to_ascii_uppercase()) {
            Some(m) if ColmapModel::CONVERTIBLE.contains(&m) => m,
            _ => bail!(
                "--model {name}: expected one of {}",
                ColmapModel::CONVERTIBLE.map(ColmapModel::name).join(", ")
            ),
        },
        None => simplest_colmap_model(&cam),
    };
    let c = colmap_from_brown(&cam, model)?;
    if !c.exact {
        eprintln!("warning: {}", conversion_note(&c));
    }
    Ok(format!(
        "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n# pipemeasure device {}: {}\n{}\n",
        p.device,
        conversion_note(&c),
        camera_text_line(CameraId(1), &c.camera)
    ))
}

fn export_opencv(p: &Profile) -> Result<String> {
    let c = opencv_from_brown(&p.camera())?;
    if !c.exact {
        eprintln!("warning: {}", conversion_note(&c));
    }
    let k = c.camera.camera_matrix;
    let fmt = |v: &[f64]| {
        v.iter()
            .map(|x| format!("{x:?}"))
            .collect::<Vec<_>>()
            .join(", ")
    };
    Ok(format!(
        "%YAML:1.0\n---\n# pipemeasure device {}: {}\nimage_width: {}\nimage_height: {}\ncamera_matrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ {} ]\ndistortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n   data: [ {} ]\nconversion_max_error_px: {:?}\n",
        p.device,
        conversion_note(&c),
        c.camera.width,
        c.camera.height,
        fmt(&[
            k[0][0], k[0][1], k[0][2], k[1][0], k[1][1], k[1][2], k[2][0], k[2][1], k[2][2]
        ]),
        fmt(&c.camera.dist_coeffs),
        c.max_error_px
    ))
}
