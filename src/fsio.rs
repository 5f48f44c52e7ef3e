//! Durable file writes: one implementation for every file the engine writes (checkpoints,
//! images, charts, tables, run metadata).
//!
//! [`write_atomic`] writes to a hidden temporary file in the destination's directory
//! (unique per process and call), flushes it to disk, renames it over the destination and
//! flushes the directory: a reader sees the old file or the complete new one, never a
//! part, and a failure (e.g. a full disk) removes the temporary file and leaves the
//! destination untouched.
//!
//! Before that, [`resolve_output`] looks at what the destination is: a symlink is
//! followed to its target (the target is replaced, the link stays); a character device
//! or a FIFO (`/dev/null`, `/dev/stdout`, a named pipe) is written directly and never
//! replaced; a directory, a block device or a socket is refused. Commands call it before
//! their work, so a bad output fails in a second, not after an hour.

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

/// What an output path names once its symlinks are followed ([`resolve_output`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum OutputTarget {
    /// A regular file, or a name nothing has yet: written atomically at this path (the
    /// symlinks' final target).
    File(PathBuf),
    /// A character device or a FIFO (`/dev/null`, `/dev/stdout`, a named pipe): written
    /// directly, in place, never replaced.
    Stream(PathBuf),
}

impl OutputTarget {
    /// The resolved path.
    pub fn path(&self) -> &Path {
        match self {
            OutputTarget::File(p) | OutputTarget::Stream(p) => p,
        }
    }
}

/// Links followed before a chain counts as a loop (Linux's own limit, `MAXSYMLINKS`).
const MAX_LINKS: usize = 40;

/// What `path` names as an output: symlinks followed (also a dangling one: its target is
/// created), then a regular file or a free name → [`OutputTarget::File`], a character
/// device or FIFO → [`OutputTarget::Stream`]; a directory, block device or socket is an
/// error naming the path and what to do.
pub fn resolve_output(path: &Path) -> Result<OutputTarget> {
    let mut p = path.to_path_buf();
    for _ in 0..MAX_LINKS {
        let meta = match std::fs::symlink_metadata(&p) {
            Ok(m) => m,
            Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(OutputTarget::File(p)),
            Err(e) => return Err(io_err(path, e)),
        };
        let t = meta.file_type();
        if t.is_symlink() {
            let link = std::fs::read_link(&p).map_err(|e| io_err(&p, e))?;
            p = match p.parent() {
                Some(dir) if link.is_relative() => dir.join(link),
                _ => link,
            };
            continue;
        }
        if t.is_file() {
            return Ok(OutputTarget::File(p));
        }
        let refuse = |what: &str| {
            let via = if p == path {
                String::new()
            } else {
                format!(" (the link's target {})", p.display())
            };
            Err(Error::Invalid(format!(
                "cannot write {}{via}: it is {what}; name a file to write",
                path.display()
            )))
        };
        if t.is_dir() {
            return refuse("a directory");
        }
        #[cfg(unix)]
        {
            use std::os::unix::fs::FileTypeExt;
            if t.is_char_device() || t.is_fifo() {
                return Ok(OutputTarget::Stream(p));
            }
            if t.is_block_device() {
                return refuse("a block device (a disk: never overwritten)");
            }
            if t.is_socket() {
                return refuse("a socket");
            }
        }
        return refuse("not a regular file");
    }
    Err(Error::Invalid(format!(
        "cannot write {}: more than {MAX_LINKS} symlinks to follow (a loop?)",
        path.display()
    )))
}

/// As [`write_atomic`], streaming the content through `fill` (buffered).
pub fn write_atomic_with(
    path: &Path,
    fill: impl FnOnce(&mut dyn Write) -> io::Result<()>,
) -> Result<()> {
    match resolve_output(path)? {
        OutputTarget::File(p) => write_file_atomic(&p, path, fill),
        OutputTarget::Stream(p) => write_stream(&p, path, fill),
    }
}

/// A character device or FIFO written in place (opened for writing only: never created,
/// truncated or replaced).
fn write_stream(
    target: &Path,
    named: &Path,
    fill: impl FnOnce(&mut dyn Write) -> io::Result<()>,
) -> Result<()> {
    (|| -> io::Result<()> {
        let file = OpenOptions::new().write(true).open(target)?;
        let mut w = BufWriter::with_capacity(1 << 20, file);
        fill(&mut w)?;
        w.flush()
    })()
    .map_err(|e| io_err(named, e))
}

/// The atomic write of a regular file at `path` (already resolved; `named` is what the
/// user gave, for messages). An existing file's permissions are kept.
fn write_file_atomic(
    path: &Path,
    named: &Path,
    fill: impl FnOnce(&mut dyn Write) -> io::Result<()>,
) -> Result<()> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let name = path.file_name().ok_or_else(|| {
        Error::Invalid(format!("cannot write {}: not a file path", named.display()))
    })?;
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    if !dir.is_dir() {
        return Err(io_err(
            named,
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
    let keep = std::fs::metadata(path).ok().map(|m| m.permissions());
    let written = (|| -> io::Result<()> {
        let file = OpenOptions::new().write(true).create_new(true).open(&tmp)?;
        let mut w = BufWriter::with_capacity(1 << 20, file);
        fill(&mut w)?;
        let file = w.into_inner().map_err(|e| e.into_error())?;
        if let Some(p) = keep {
            file.set_permissions(p)?;
        }
        file.sync_all()?;
        drop(file);
        std::fs::rename(&tmp, path)
    })();
    if let Err(e) = written {
        let _ = std::fs::remove_file(&tmp);
        return Err(io_err(
            named,
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A symlink's target is replaced and the link stays (a dangling one makes its
    /// target); a FIFO is written in place and stays a FIFO; a folder is refused and
    /// left as it was; an existing file keeps its permissions. Before, each of these
    /// paths was replaced by a new regular file.
    #[test]
    fn outputs_are_what_they_name() {
        use std::os::unix::fs::{FileTypeExt, PermissionsExt};
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let target = d.join("target");
        std::fs::write(&target, b"old").unwrap();
        std::fs::set_permissions(&target, std::fs::Permissions::from_mode(0o640)).unwrap();
        let link = d.join("link");
        std::os::unix::fs::symlink("target", &link).unwrap();
        write_atomic(&link, b"new").unwrap();
        assert!(std::fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
        assert_eq!(std::fs::read(&target).unwrap(), b"new");
        let mode = std::fs::metadata(&target).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o640);
        let dangling = d.join("dangling");
        std::os::unix::fs::symlink(d.join("made"), &dangling).unwrap();
        write_atomic(&dangling, b"made").unwrap();
        assert_eq!(std::fs::read(d.join("made")).unwrap(), b"made");
        // A loop of links is an error, not a hang.
        std::os::unix::fs::symlink(d.join("b"), d.join("a")).unwrap();
        std::os::unix::fs::symlink(d.join("a"), d.join("b")).unwrap();
        assert!(write_atomic(&d.join("a"), b"x").is_err());

        let fifo = d.join("fifo");
        assert!(std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap()
            .success());
        assert_eq!(
            resolve_output(&fifo).unwrap(),
            OutputTarget::Stream(fifo.clone())
        );
        let reader = {
            let fifo = fifo.clone();
            std::thread::spawn(move || std::fs::read(fifo).unwrap())
        };
        write_atomic(&fifo, b"through the pipe").unwrap();
        assert_eq!(reader.join().unwrap(), b"through the pipe");
        assert!(std::fs::symlink_metadata(&fifo)
            .unwrap()
            .file_type()
            .is_fifo());
        // A character device is a stream too (only its metadata is read here).
        assert_eq!(
            resolve_output(Path::new("/dev/null")).unwrap(),
            OutputTarget::Stream("/dev/null".into())
        );

        let folder = d.join("folder");
        std::fs::create_dir(&folder).unwrap();
        let e = write_atomic(&folder, b"x").unwrap_err().to_string();
        assert!(e.contains("is a directory"), "{e}");
        assert!(folder.is_dir() && folder.read_dir().unwrap().next().is_none());
        // Nothing but the files made here: no temporary file left behind.
        let mut names: Vec<_> = std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().file_name().into_string().unwrap())
            .collect();
        names.sort();
        assert_eq!(
            names,
            ["a", "b", "dangling", "fifo", "folder", "link", "made", "target"]
        );
    }
}
