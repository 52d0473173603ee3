//! All-or-nothing outputs.
//!
//! * One file: written to a hidden temporary file beside the target, flushed, and renamed over
//!   it only once complete ([`write_atomic`]), so a failed run never leaves a half-written file.
//! * Several files that belong together (undistorted frames and their `cameras.txt`, a profile
//!   and its report): each output is staged — a [`StagedDir`] or a [`StagedFile`] beside its
//!   destination — and every stage is moved into place only after all of them were written
//!   ([`StagedDir::commit`], [`StagedFile::commit`]). A failure before the commit removes the
//!   stages and leaves the destinations as they were.
//! * A temporary left behind by a killed run (`.NAME.tmp-PID`) is removed by the next run that
//!   writes the same destination, once no process with that id is alive (where the system says:
//!   Linux's `/proc`).
//! * Destinations are checked before the work ([`check_writable`], [`check_writable_dir`]), so
//!   that minutes of computation are not lost to a missing folder or a read-only disk.

use std::fs::{self, File};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use super::error::WriteError;

/// Writes `path` atomically with `write`, which receives a buffered writer.
///
/// # Errors
///
/// [`WriteError`] naming `path` when the temporary file cannot be created, written, flushed or
/// renamed; the temporary file is removed on failure.
pub fn write_atomic<F>(path: &Path, write: F) -> Result<(), WriteError>
where
    F: FnOnce(&mut BufWriter<File>) -> std::io::Result<()>,
{
    StagedFile::write(path, write)?.commit()
}

/// Writes bytes to `path` atomically.
///
/// # Errors
///
/// As [`write_atomic`].
pub fn write_bytes_atomic(path: &Path, bytes: &[u8]) -> Result<(), WriteError> {
    write_atomic(path, |w| w.write_all(bytes))
}

/// The prefix of every temporary name of `path` (`.NAME.tmp-`), followed by the process id.
fn temporary_prefix(path: &Path) -> String {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    format!(".{name}.tmp-")
}

/// A hidden temporary name in the same directory (so the rename stays on one file system).
fn temporary_path(path: &Path) -> PathBuf {
    path.with_file_name(format!("{}{}", temporary_prefix(path), std::process::id()))
}

/// The folder `path` is in (`.` for a bare name).
fn parent_of(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// Whether the process `pid` is known to be gone. Only Linux's `/proc` can tell; elsewhere a
/// temporary is never taken for stale.
fn process_is_gone(pid: u32) -> bool {
    Path::new("/proc/self").exists() && !Path::new(&format!("/proc/{pid}")).exists()
}

/// Removes the temporaries of `path` that processes no longer alive left behind (a kill during
/// a write). Best effort: a temporary that cannot be removed stays.
fn remove_stale_temporaries(path: &Path) {
    let prefix = temporary_prefix(path);
    let Ok(entries) = fs::read_dir(parent_of(path)) else {
        return;
    };
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(pid) = name
            .to_str()
            .and_then(|n| n.strip_prefix(&prefix))
            .and_then(|p| p.parse::<u32>().ok())
        else {
            continue;
        };
        if pid != std::process::id() && process_is_gone(pid) {
            let stale = entry.path();
            let _ = if stale.is_dir() {
                fs::remove_dir_all(&stale)
            } else {
                fs::remove_file(&stale)
            };
        }
    }
}

/// One output file written completely beside its destination, moved into place by
/// [`StagedFile::commit`]; dropped uncommitted, it is removed.
#[derive(Debug)]
pub struct StagedFile {
    dest: PathBuf,
    tmp: PathBuf,
    committed: bool,
}

impl StagedFile {
    /// Writes the staged file with `write` (buffered, flushed and synced).
    ///
    /// # Errors
    ///
    /// [`WriteError`] naming the destination, which is refused at once when it is a folder
    /// (the file could be staged but never moved into place); nothing is left behind.
    pub fn write<F>(dest: &Path, write: F) -> Result<Self, WriteError>
    where
        F: FnOnce(&mut BufWriter<File>) -> std::io::Result<()>,
    {
        refuse_folder(dest)?;
        remove_stale_temporaries(dest);
        let staged = StagedFile {
            dest: dest.to_path_buf(),
            tmp: temporary_path(dest),
            committed: false,
        };
        let result = (|| {
            let file = File::create(&staged.tmp)?;
            let mut w = BufWriter::with_capacity(1 << 20, file);
            write(&mut w)?;
            let file = w.into_inner().map_err(|e| e.into_error())?;
            file.sync_all()
        })();
        // On failure `staged` is dropped here, which removes the temporary.
        result.map_err(|e| WriteError::new(dest, e))?;
        Ok(staged)
    }

    /// Writes the staged file with `write`, given the temporary's path: for writers that open
    /// their own file (the E57 writer reads back and seeks as it writes). `write` must leave the
    /// file complete and closed.
    ///
    /// # Errors
    ///
    /// As [`StagedFile::write`].
    pub fn write_at<F>(dest: &Path, write: F) -> Result<Self, WriteError>
    where
        F: FnOnce(&Path) -> std::io::Result<()>,
    {
        refuse_folder(dest)?;
        remove_stale_temporaries(dest);
        let staged = StagedFile {
            dest: dest.to_path_buf(),
            tmp: temporary_path(dest),
            committed: false,
        };
        let result = write(&staged.tmp).and_then(|()| File::open(&staged.tmp)?.sync_all());
        result.map_err(|e| WriteError::new(dest, e))?;
        Ok(staged)
    }

    /// The destination.
    #[must_use]
    pub fn destination(&self) -> &Path {
        &self.dest
    }

    /// Moves the file into place (replacing the destination).
    ///
    /// # Errors
    ///
    /// [`WriteError`] naming the destination when the rename fails; the staged file is removed.
    pub fn commit(mut self) -> Result<(), WriteError> {
        fs::rename(&self.tmp, &self.dest).map_err(|e| WriteError::new(&self.dest, e))?;
        self.committed = true;
        Ok(())
    }
}

impl Drop for StagedFile {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_file(&self.tmp);
        }
    }
}

/// A folder of outputs staged beside its destination (a hidden `.NAME.tmp-PID` folder in the
/// same parent): write into [`StagedDir::path`], then [`StagedDir::commit`]. Dropped
/// uncommitted, the staged folder and everything in it are removed.
#[derive(Debug)]
pub struct StagedDir {
    dest: PathBuf,
    tmp: PathBuf,
    committed: bool,
}

impl StagedDir {
    /// Creates the staging folder (and the destination's parent folders).
    ///
    /// # Errors
    ///
    /// [`WriteError`] naming the destination: it exists and is not a folder, or the folders
    /// cannot be created.
    pub fn new(dest: &Path) -> Result<Self, WriteError> {
        if dest.exists() && !dest.is_dir() {
            return Err(WriteError::new(
                dest,
                std::io::Error::new(
                    std::io::ErrorKind::AlreadyExists,
                    "exists and is not a folder",
                ),
            ));
        }
        let parent = parent_of(dest);
        fs::create_dir_all(parent).map_err(|e| WriteError::new(parent, e))?;
        remove_stale_temporaries(dest);
        let tmp = temporary_path(dest);
        if tmp.exists() {
            fs::remove_dir_all(&tmp).map_err(|e| WriteError::new(&tmp, e))?;
        }
        fs::create_dir(&tmp).map_err(|e| WriteError::new(dest, e))?;
        Ok(StagedDir {
            dest: dest.to_path_buf(),
            tmp,
            committed: false,
        })
    }

    /// Where to write the outputs.
    #[must_use]
    pub fn path(&self) -> &Path {
        &self.tmp
    }

    /// The destination.
    #[must_use]
    pub fn destination(&self) -> &Path {
        &self.dest
    }

    /// Moves the outputs into place: the whole folder when the destination does not exist yet,
    /// otherwise each staged file into it (replacing files of the same name, leaving the others).
    ///
    /// # Errors
    ///
    /// [`WriteError`] naming the file that could not be moved.
    pub fn commit(mut self) -> Result<(), WriteError> {
        if !self.dest.exists() {
            fs::rename(&self.tmp, &self.dest).map_err(|e| WriteError::new(&self.dest, e))?;
            self.committed = true;
            return Ok(());
        }
        let entries = fs::read_dir(&self.tmp).map_err(|e| WriteError::new(&self.dest, e))?;
        let mut names: Vec<_> = entries
            .map(|e| e.map(|e| e.file_name()))
            .collect::<Result<_, _>>()
            .map_err(|e| WriteError::new(&self.dest, e))?;
        names.sort();
        for name in names {
            let to = self.dest.join(&name);
            fs::rename(self.tmp.join(&name), &to).map_err(|e| WriteError::new(&to, e))?;
        }
        // `drop` removes the (now empty) staging folder.
        Ok(())
    }
}

impl Drop for StagedDir {
    fn drop(&mut self) {
        if !self.committed {
            let _ = fs::remove_dir_all(&self.tmp);
        }
    }
}

/// A file cannot be written where a folder is.
fn refuse_folder(path: &Path) -> Result<(), WriteError> {
    if path.is_dir() {
        return Err(WriteError::new(
            path,
            std::io::Error::new(std::io::ErrorKind::IsADirectory, "is a folder"),
        ));
    }
    Ok(())
}

/// Checks, before any work, that a file can be written at `path`: it is not a folder, its folder
/// exists, and a new file can be created there (a probe file is created and removed).
///
/// # Errors
///
/// [`WriteError`] naming `path` with the reason.
pub fn check_writable(path: &Path) -> Result<(), WriteError> {
    refuse_folder(path)?;
    let parent = parent_of(path);
    if !parent.is_dir() {
        return Err(WriteError::new(
            path,
            std::io::Error::new(
                std::io::ErrorKind::NotFound,
                format!("folder {} does not exist", parent.display()),
            ),
        ));
    }
    probe(parent).map_err(|e| WriteError::new(path, e))
}

/// Checks, before any work, that a folder of outputs can be written at `dir`: it is a folder
/// that accepts new files, or it does not exist and its nearest existing ancestor is a folder
/// that accepts new files (it will be created).
///
/// # Errors
///
/// [`WriteError`] naming `dir` with the reason.
pub fn check_writable_dir(dir: &Path) -> Result<(), WriteError> {
    let existing = dir
        .ancestors()
        .map(|a| {
            if a.as_os_str().is_empty() {
                Path::new(".")
            } else {
                a
            }
        })
        .find(|a| a.exists())
        .unwrap_or(Path::new("."));
    if !existing.is_dir() {
        return Err(WriteError::new(
            dir,
            std::io::Error::new(
                std::io::ErrorKind::NotADirectory,
                format!("{} is not a folder", existing.display()),
            ),
        ));
    }
    probe(existing).map_err(|e| WriteError::new(dir, e))
}

/// Creates and removes a hidden file in `dir`.
fn probe(dir: &Path) -> std::io::Result<()> {
    let p = dir.join(format!(".pipemeasure-probe-{}", std::process::id()));
    File::create(&p)?;
    fs::remove_file(&p)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failed_write_leaves_nothing_behind() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.txt");
        fs::write(&path, "old").unwrap();
        let err = write_atomic(&path, |w| {
            w.write_all(b"partial")?;
            Err(std::io::Error::other("boom"))
        })
        .unwrap_err();
        assert!(err.to_string().contains("out.txt"));
        assert_eq!(fs::read_to_string(&path).unwrap(), "old");
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    /// A destination that is a folder is refused when the file is staged, not when it is
    /// committed: nothing is written, and the caller's other staged files are never moved in.
    #[test]
    fn staging_onto_a_folder_is_refused_at_once() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("taken.1");
        fs::create_dir(&path).unwrap();
        let mut called = false;
        let err = StagedFile::write(&path, |_| {
            called = true;
            Ok(())
        })
        .unwrap_err();
        assert!(!called);
        assert!(err.to_string().contains("taken.1"), "{err}");
        assert!(StagedFile::write_at(&path, |_| Ok(())).is_err());
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn successful_write_replaces_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.txt");
        write_bytes_atomic(&path, b"new").unwrap();
        assert_eq!(fs::read_to_string(&path).unwrap(), "new");
    }

    #[test]
    fn staged_dir_moves_into_place_only_on_commit() {
        let dir = tempfile::tempdir().unwrap();
        let dest = dir.path().join("out");
        {
            let staged = StagedDir::new(&dest).unwrap();
            fs::write(staged.path().join("a.txt"), "a").unwrap();
            // Dropped without a commit: nothing appears, nothing is left.
        }
        assert!(!dest.exists());
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 0);
        let staged = StagedDir::new(&dest).unwrap();
        fs::write(staged.path().join("a.txt"), "a").unwrap();
        staged.commit().unwrap();
        assert_eq!(fs::read_to_string(dest.join("a.txt")).unwrap(), "a");
        // Into an existing folder: files replaced one by one, others kept.
        fs::write(dest.join("keep.txt"), "k").unwrap();
        let staged = StagedDir::new(&dest).unwrap();
        fs::write(staged.path().join("a.txt"), "b").unwrap();
        staged.commit().unwrap();
        assert_eq!(fs::read_to_string(dest.join("a.txt")).unwrap(), "b");
        assert_eq!(fs::read_to_string(dest.join("keep.txt")).unwrap(), "k");
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn a_dead_process_temporary_is_removed_by_the_next_write() {
        if !Path::new("/proc/self").exists() {
            return; // only Linux's /proc says which processes are alive
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("out.txt");
        // No process has id u32::MAX - 1 (Linux ids stay below 2^22).
        let stale = dir.path().join(format!(".out.txt.tmp-{}", u32::MAX - 1));
        fs::write(&stale, "half").unwrap();
        write_bytes_atomic(&path, b"new").unwrap();
        assert!(!stale.exists());
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn writability_is_checked_before_the_work() {
        let dir = tempfile::tempdir().unwrap();
        check_writable(&dir.path().join("x.json")).unwrap();
        let e = check_writable(&dir.path().join("missing/x.json")).unwrap_err();
        assert!(e.to_string().contains("does not exist"), "{e}");
        let e = check_writable(dir.path()).unwrap_err();
        assert!(e.to_string().contains("is a folder"), "{e}");
        check_writable_dir(&dir.path().join("new/deeper")).unwrap();
        let file = dir.path().join("f");
        fs::write(&file, "").unwrap();
        let e = check_writable_dir(&file.join("sub")).unwrap_err();
        assert!(e.to_string().contains("is not a folder"), "{e}");
        assert_eq!(fs::read_dir(dir.path()).unwrap().count(), 1);
    }
}
