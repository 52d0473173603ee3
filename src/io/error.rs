//! Read and write errors that name the file and, where it applies, the line or byte offset.

use std::fmt;
use std::path::PathBuf;

/// Where in a file a read error happened.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Location {
    /// 1-based line of a text file.
    Line(usize),
    /// Byte offset of a binary file.
    Byte(u64),
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Location::Line(l) => write!(f, ":{l}"),
            Location::Byte(b) => write!(f, " (byte {b})"),
        }
    }
}

/// A file that could not be read.
#[derive(Debug, thiserror::Error)]
#[error("{}{}: {kind}", .path.display(), .location.map(|l| l.to_string()).unwrap_or_default())]
pub struct ReadError {
    /// The file.
    pub path: PathBuf,
    /// Where in it, if known.
    pub location: Option<Location>,
    /// What went wrong.
    pub kind: ReadErrorKind,
}

impl ReadError {
    /// An error with no location.
    pub fn new(path: impl Into<PathBuf>, kind: ReadErrorKind) -> Self {
        ReadError {
            path: path.into(),
            location: None,
            kind,
        }
    }

    /// An error at a 1-based line.
    pub fn at_line(path: impl Into<PathBuf>, line: usize, kind: ReadErrorKind) -> Self {
        ReadError {
            path: path.into(),
            location: Some(Location::Line(line)),
            kind,
        }
    }

    /// An error at a byte offset.
    pub fn at_byte(path: impl Into<PathBuf>, byte: u64, kind: ReadErrorKind) -> Self {
        ReadError {
            path: path.into(),
            location: Some(Location::Byte(byte)),
            kind,
        }
    }
}

/// What went wrong while reading.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum ReadErrorKind {
    /// The operating system refused.
    #[error("cannot read file: {0}")]
    Io(#[source] std::io::Error),
    /// The file or directory does not exist.
    #[error("not found")]
    NotFound,
    /// A file was expected, a directory was found.
    #[error("is a directory, expected a file")]
    IsDirectory,
    /// A text field could not be parsed.
    #[error("field {field} is {value:?}, expected {expected}")]
    Field {
        /// Which field (e.g. `CAMERA_ID`).
        field: &'static str,
        /// The text found.
        value: String,
        /// What was expected.
        expected: &'static str,
    },
    /// A line has too few fields.
    #[error("expected {expected}, found {found} fields")]
    FieldCount {
        /// Description of the expected fields.
        expected: String,
        /// Fields found.
        found: usize,
    },
    /// The file ends early.
    #[error("file ends early: {0}")]
    Truncated(String),
    /// The content is inconsistent.
    #[error("{0}")]
    Invalid(String),
    /// The file is not in the expected format at all.
    #[error("not a {0} file")]
    WrongFormat(&'static str),
    /// A header lacks a required property.
    #[error("header has no `{0}` property")]
    MissingProperty(&'static str),
    /// An image decoder failed.
    #[error("cannot decode image: {0}")]
    Image(#[source] image::ImageError),
    /// A JSON document does not match its schema.
    #[error("{field}: {message}")]
    Json {
        /// Path of the offending field, e.g. `intrinsics.c`.
        field: String,
        /// What is wrong.
        message: String,
    },
}

/// A file that could not be written.
#[derive(Debug, thiserror::Error)]
#[error("cannot write {}: {source}", .path.display())]
pub struct WriteError {
    /// The file.
    pub path: PathBuf,
    /// The cause.
    #[source]
    pub source: std::io::Error,
}

impl WriteError {
    /// Wraps an I/O error for `path`.
    pub fn new(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        WriteError {
            path: path.into(),
            source,
        }
    }
}

/// Maps an `io::Error` on opening a file to a read error (not found and a directory where a file
/// was expected are kinds of their own).
pub(crate) fn open_error(path: impl Into<PathBuf>, e: std::io::Error) -> ReadError {
    let path = path.into();
    let kind = match e.kind() {
        std::io::ErrorKind::NotFound => ReadErrorKind::NotFound,
        std::io::ErrorKind::IsADirectory => ReadErrorKind::IsDirectory,
        _ if path.is_dir() => ReadErrorKind::IsDirectory,
        _ => ReadErrorKind::Io(e),
    };
    ReadError::new(path, kind)
}

/// Opens a file for reading; a directory is refused here (the OS opens directories and fails
/// only at the first read, with a less helpful message).
pub(crate) fn open_file(path: &std::path::Path) -> Result<std::fs::File, ReadError> {
    let file = std::fs::File::open(path).map_err(|e| open_error(path, e))?;
    match file.metadata() {
        Ok(m) if m.is_dir() => Err(ReadError::new(path, ReadErrorKind::IsDirectory)),
        _ => Ok(file),
    }
}
