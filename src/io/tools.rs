//! The external programs the product runs — COLMAP (sparse reconstruction) and ffmpeg with
//! ffprobe (video) — found on `PATH` or not, with the version they print and what this build
//! of COLMAP can do (Debian's is built without CUDA: no dense stereo). `pipemeasure doctor`
//! prints them; `calibrate` checks what its options need before it starts.

use std::process::Command;

/// An external program the product runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[non_exhaustive]
pub enum Tool {
    /// COLMAP: the sparse reconstruction of frames without a given model.
    Colmap,
    /// ffmpeg: decoding videos (`--video`, `frames`).
    Ffmpeg,
    /// ffprobe: reading a video's size and rate.
    Ffprobe,
}

impl Tool {
    /// Every tool, in the order they are reported.
    pub const ALL: [Tool; 3] = [Tool::Colmap, Tool::Ffmpeg, Tool::Ffprobe];

    /// The program's name on `PATH`.
    #[must_use]
    pub fn program(self) -> &'static str {
        match self {
            Tool::Colmap => "colmap",
            Tool::Ffmpeg => "ffmpeg",
            Tool::Ffprobe => "ffprobe",
        }
    }

    /// What the product needs it for.
    #[must_use]
    pub fn needed_for(self) -> &'static str {
        match self {
            Tool::Colmap => {
                "reconstructing frames without a given SfM model (calibrate without --sfm)"
            }
            Tool::Ffmpeg => "reading videos (calibrate --video, frames)",
            Tool::Ffprobe => "reading a video's size and frame rate (calibrate --video, frames)",
        }
    }

    /// How to install it on Debian and Ubuntu.
    #[must_use]
    pub fn install(self) -> &'static str {
        match self {
            Tool::Colmap => "sudo apt-get install -y colmap",
            Tool::Ffmpeg | Tool::Ffprobe => "sudo apt-get install -y ffmpeg",
        }
    }

    /// The arguments that make it print its version and exit.
    fn version_args(self) -> &'static [&'static str] {
        match self {
            Tool::Colmap => &["help"],
            Tool::Ffmpeg | Tool::Ffprobe => &["-version"],
        }
    }
}

/// What was found of a tool.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ToolStatus {
    /// The tool.
    pub tool: Tool,
    /// Its version line (the first line it prints), `None` when it is not on `PATH` or fails
    /// to print it (a broken install).
    pub version: Option<String>,
    /// COLMAP only: whether this build has CUDA (dense stereo needs it); `None` for the others
    /// and when it does not say.
    pub cuda: Option<bool>,
}

impl ToolStatus {
    /// Whether the program was found.
    #[must_use]
    pub fn found(&self) -> bool {
        self.version.is_some()
    }
}

/// Runs `tool` to read its version (a program that exits with an error counts as missing):
/// its first line of output (stdout, else stderr), and for
/// COLMAP whether its build line says `with CUDA` or `without CUDA`.
#[must_use]
pub fn probe(tool: Tool) -> ToolStatus {
    let ran = Command::new(tool.program())
        .args(tool.version_args())
        .output();
    let Some(out) = ran.ok().filter(|o| o.status.success()) else {
        return ToolStatus {
            tool,
            version: None,
            cuda: None,
        };
    };
    let text = format!(
        "{}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let version = text
        .lines()
        .map(str::trim)
        .find(|l| !l.is_empty())
        .map(str::to_string)
        .unwrap_or_else(|| tool.program().to_string());
    let cuda = (tool == Tool::Colmap)
        .then(|| {
            if text.contains("without CUDA") {
                Some(false)
            } else if text.contains("with CUDA") {
                Some(true)
            } else {
                None
            }
        })
        .flatten();
    ToolStatus {
        tool,
        version: Some(version),
        cuda,
    }
}

/// The machine: logical cores and memory (total and available, bytes; `None` where the
/// system does not say, as outside Linux).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Machine {
    /// Logical cores rayon will use.
    pub cores: usize,
    /// Total memory (bytes).
    pub memory_total: Option<u64>,
    /// Memory available to a new process (bytes).
    pub memory_available: Option<u64>,
}

/// The machine this runs on ([`Machine`]); memory from `/proc/meminfo`.
#[must_use]
pub fn machine() -> Machine {
    let meminfo = std::fs::read_to_string("/proc/meminfo").unwrap_or_default();
    let field = |name: &str| {
        meminfo.lines().find_map(|l| {
            let rest = l.strip_prefix(name)?.strip_prefix(':')?;
            let kb: u64 = rest.trim().trim_end_matches("kB").trim().parse().ok()?;
            Some(kb * 1024)
        })
    };
    Machine {
        cores: rayon::current_num_threads(),
        memory_total: field("MemTotal"),
        memory_available: field("MemAvailable"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every tool says what it is for and how to install it.
    #[test]
    fn every_tool_has_a_name_a_use_and_an_install_command() {
        for t in Tool::ALL {
            assert!(!t.program().is_empty() && !t.needed_for().is_empty());
            assert!(t.install().starts_with("sudo apt-get install -y "));
        }
    }

    /// The machine has at least one core.
    #[test]
    fn the_machine_has_cores() {
        assert!(machine().cores >= 1);
    }
}
