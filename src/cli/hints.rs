//! The library's errors as the command line says them: where an error names an input
//! (the SfM model, a scale, the device), the command line names the option that gives it. The
//! library's messages name only what the input is, so that other front ends can say it their
//! way.

use pipemeasure::calibrate::input::InputError;
use pipemeasure::measure::scale::ScaleError;
use pipemeasure::measure::site::{SiteError, SiteInput};
use pipemeasure::profile::{ProfileError, backup_path};
use pipemeasure::video::VideoError;

/// The option that gives a site's input, with its value's placeholder where it takes one.
fn option(input: SiteInput) -> &'static str {
    match input {
        SiteInput::Device => "--device NAME",
        SiteInput::Sfm => "--sfm",
        SiteInput::Frames => "--frames",
        SiteInput::TlsTargets => "--tls-targets",
        SiteInput::TlsIds => "--tls-ids",
        SiteInput::Scale => "--scale",
        _ => "an option",
    }
}

/// The command line's words for `err`, when they differ from the library's.
pub fn on_the_command_line(err: &(dyn std::error::Error + 'static)) -> Option<String> {
    if let Some(e) = err.downcast_ref::<SiteError>() {
        return site(e);
    }
    if let Some(e) = err.downcast_ref::<ProfileError>() {
        return profile(e);
    }
    if let Some(e) = err.downcast_ref::<ScaleError>() {
        return scale(e);
    }
    if let Some(InputError::MissingFrames {
        missing,
        images,
        frames,
        first,
    }) = err.downcast_ref::<InputError>()
    {
        return Some(format!(
            "{missing} of the model's {images} images are not in {} (first: {}): is --frames the folder the model was built from?",
            frames.display(),
            first.join(", ")
        ));
    }
    if let Some(VideoError::NotInstalled(program)) = err.downcast_ref::<VideoError>() {
        return Some(format!(
            "`{program}` is not installed or not on PATH (Debian/Ubuntu: `apt-get install -y ffmpeg`); or extract the frames yourself and pass --frames DIR"
        ));
    }
    None
}

/// `err` as the command line says it.
pub fn said(err: &(dyn std::error::Error + 'static)) -> String {
    on_the_command_line(err).unwrap_or_else(|| err.to_string())
}

fn site(e: &SiteError) -> Option<String> {
    Some(match e {
        SiteError::NoDevice => {
            "--device NAME is needed to scale the cloud from the targets (or give --scale)".into()
        }
        SiteError::NotFound { input, path } => {
            format!("{} {}: not found", option(*input), path.display())
        }
        SiteError::NotBeside { input, .. } => format!("{e}; give it with {}", option(*input)),
        SiteError::UnknownTlsId { .. } => format!("{}: {e}", option(SiteInput::TlsIds)),
        SiteError::BadScale(s) => format!(
            "{} {s}: must be a positive number",
            option(SiteInput::Scale)
        ),
        SiteError::Profile(p) => profile(p)?,
        _ => return None,
    })
}

fn profile(e: &ProfileError) -> Option<String> {
    Some(match e {
        ProfileError::Exists(path) => format!(
            "{} exists; pass --force to replace it (the old one is kept as a numbered backup, {})",
            path.display(),
            backup_path(path, 1).display()
        ),
        ProfileError::NotAName(name) => format!(
            "`{name}` is not a device name: a name has no path separator, does not start with `.` and does not end with `.json` (a profile is written as NAME.json in the profile folder; write elsewhere with --out PATH)"
        ),
        ProfileError::NoDataFolder => "no folder to write the profile to: no user data folder (the home folder is unknown) and $PIPEMEASURE_CALIBRATIONS is not set; give one, or write with --out PATH".into(),
        _ => return None,
    })
}

fn scale(e: &ScaleError) -> Option<String> {
    match e {
        ScaleError::TooManyTls { found, max } => Some(format!(
            "{found} TLS targets: the automatic association handles at most {max} (its time grows faster than the square of the list); give this site's targets with --tls-ids or a shorter list"
        )),
        _ => None,
    }
}
