//! Durable file writes: one implementation for every file the engine writes (checkpoints,
//! images, charts, tables, run metadata).
//!
//! [`write_atomic`] writes to a hidden temporary file in the destination's directory
//! (unique per process and call), flushes it to disk, renames it over the destination and
//! flushes the directory: a reader sees the old file or the complete new one, never a
//! part, and a failure (e.g. a full disk) removes the temporary file and leaves the
//! destination untouched.

use std::fs::{File, OpenOptions};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use crate::error::{Error, Result};

fn io_err(path: &Path, error: io::Error) -> Error {
    Error::Io {
        path: path.display().to_string(),
        error,
    }
}

/// Writes `bytes` to `path` atomically and durably (see the module notes).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomic_with(path, |w| w.write_all(bytes))
}

/// As [`write_atomic`], streaming the content through `fill` (buffered).
pub fn write_atomic_with(
    path: &Path,
    fill: impl FnOnce(&mut dyn Write) -> io::Result<()>,
) -> Result<()> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let name = path.file_name().ok_or_else(|| {
        Error::Invalid(format!("cannot write {}: not a file path", path.display()))
    })?;
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    if !dir.is_dir() {
        return Err(io_err(
            path,
            io::Error::new(
                io::ErrorKind::NotFound,
                format!("directory {} does not exist", dir.display()),
            ),
        ));
    }
    let tmp = dir.join(format!(
        ".{}.{}.{}.tmp",
        name.to_string_lossy(),
        std::process::id(),
        COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    let written = (|| -> io::Result<()> {
        let file = OpenOptions::new().write(true).create_new(true).open(&tmp)?;
        let mut w = BufWriter::with_capacity(1 << 20, file);
        fill(&mut w)?;
        let file = w.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        drop(file);
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = written {
        let _ = std::fs::remove_file(&tmp);
        return Err(io_err(
            path,
            io::Error::new(e.kind(), format!("{e} (writing via {})", tmp.display())),
        ));
    }
    sync_dir(dir);
    Ok(())
}

/// Writes `bytes` to `path` (created or truncated) and flushes them to disk, without a
/// rename: for files that a later rename installs (e.g. the checkpoint pair).
pub fn write_synced(path: &Path, bytes: &[u8]) -> Result<()> {
    (|| -> io::Result<()> {
        let mut f = File::create(path)?;
        f.write_all(bytes)?;
        f.sync_all()
    })()
    .map_err(|e| io_err(path, e))
}

/// Flushes a directory's entries (renames, new files) to disk; best effort (not every
/// platform can sync a directory).
pub fn sync_dir(dir: &Path) {
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
}

/// `name.ext` → `name.ext.tmp` (the visible temporary name of a file a later rename
/// installs).
pub fn tmp_path(path: &Path) -> PathBuf {
    let mut s = path.as_os_str().to_owned();
    s.push(".tmp");
    PathBuf::from(s)
}
