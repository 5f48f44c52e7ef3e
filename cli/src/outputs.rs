//! The one guard every output file goes through before a command's work: what the path
//! is (a symlink is followed; a folder, block device or socket is refused; `/dev/null`, a
//! FIFO and other character devices are written in place — [`svraster::fsio`]), the file
//! types the command writes, never a file or folder being read, and never a run's own
//! files.

use std::path::Path;

use anyhow::bail;
use svraster::fsio::{resolve_output, OutputTarget};

use super::inputs::resolved;

/// What a run directory holds and only `svraster train` writes: an output of another
/// command with one of these names in a run directory would replace the run.
pub const RUN_FILES: [&str; 7] = [
    "model.safetensors",
    "optimizer.safetensors",
    "optimizer.bin",
    "config.json",
    "stats.jsonl",
    "training.png",
    ".lock",
];

/// Whether `dir` is a run directory of `svraster train`: its lock or log, or a config
/// beside a model.
pub fn is_run_dir(dir: &Path) -> bool {
    dir.join(".lock").exists()
        || dir.join("stats.jsonl").is_file()
        || (dir.join("config.json").is_file() && dir.join("model.safetensors").is_file())
}

/// An output file's rule.
pub struct OutputFile<'a> {
    /// The flag that names it, for messages (`--out`, `--screenshot`).
    pub flag: &'a str,
    /// What is written, for messages ("the mesh").
    pub what: &'a str,
    /// The extensions it may have (lower case, without the dot); the first is suggested.
    pub extensions: &'a [&'a str],
    /// Files and folders the command reads, each with its role ("the model", "the
    /// dataset"): the output may not be one of them or lie in one of the folders.
    pub inputs: &'a [(&'a str, &'a Path)],
}

/// Checks `out` against `rule` (see the module notes) and returns what it resolves to.
pub fn check_file(out: &Path, rule: &OutputFile) -> anyhow::Result<OutputTarget> {
    let flag = rule.flag;
    let target = resolve_output(out).map_err(|e| match e {
        svraster::error::Error::Invalid(m) => anyhow::anyhow!("{flag}: {m}"),
        e => anyhow::anyhow!("{flag} {}: {e}", out.display()),
    })?;
    let OutputTarget::File(p) = &target else {
        // A device or a pipe: written in place, whatever its name.
        return Ok(target);
    };
    for named in [out, p.as_path()] {
        let name = named.file_name().and_then(|n| n.to_str()).unwrap_or("");
        let dir = match named.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        if RUN_FILES.contains(&name) && is_run_dir(dir) {
            let via = if named == out {
                String::new()
            } else {
                format!(" (the link's target {})", named.display())
            };
            bail!(
                "{flag} {} would replace the run's own {name} in {}{via}; write {} to \
                 another name (e.g. {})",
                out.display(),
                dir.display(),
                rule.what,
                dir.join(format!("NAME.{}", rule.extensions[0])).display()
            );
        }
    }
    let o = resolved(p);
    for &(role, input) in rule.inputs {
        let i = resolved(input);
        let is_input = o == i || same_file(p, input);
        if is_input || (input.is_dir() && o.starts_with(&i)) {
            bail!(
                "{flag} {} would replace {}: it {} {role} {}, which this command reads; \
                 write {} elsewhere",
                out.display(),
                if is_input {
                    "an input"
                } else {
                    "a file being read"
                },
                if is_input { "is" } else { "is inside" },
                input.display(),
                rule.what
            );
        }
    }
    let ext = out
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    if !ext.as_deref().is_some_and(|e| rule.extensions.contains(&e)) {
        let list = rule
            .extensions
            .iter()
            .map(|e| format!(".{e}"))
            .collect::<Vec<_>>()
            .join(" or ");
        bail!(
            "{flag} {}: {} is written as {list}; name the file NAME.{}",
            out.display(),
            rule.what,
            rule.extensions[0]
        );
    }
    Ok(target)
}

/// Whether two existing paths are the same file (device and inode; hard links too).
fn same_file(a: &Path, b: &Path) -> bool {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        match (std::fs::metadata(a), std::fs::metadata(b)) {
            (Ok(x), Ok(y)) => x.dev() == y.dev() && x.ino() == y.ino(),
            _ => false,
        }
    }
    #[cfg(not(unix))]
    {
        let _ = (a, b);
        false
    }
}

/// An output folder (`render --out DIR`): not a file (a symlink to a folder is followed),
/// not a run directory (its frames could replace the run's files), and outside every
/// folder being read (the dataset: its photos share the renders' names).
pub fn check_dir(out: &Path, inputs: &[(&str, &Path)]) -> anyhow::Result<()> {
    if out.exists() && !out.is_dir() {
        bail!(
            "--out {}: it is a file; the renders go into a folder (one PNG per frame), or \
             name a video NAME.mp4 with --path",
            out.display()
        );
    }
    if out.is_dir() && is_run_dir(out) {
        bail!(
            "--out {}: it is a run directory; its files could be replaced by the frames. \
             Write them to a folder of their own, e.g. {}",
            out.display(),
            out.join("renders").display()
        );
    }
    let o = resolved(out);
    for &(role, input) in inputs {
        let i = resolved(input);
        if input.is_dir() && o.starts_with(&i) {
            bail!(
                "--out {} is inside {role} {}, which this command reads: the renders (one \
                 STEM.png per frame) could replace its files. Write them to a folder \
                 outside it",
                out.display(),
                input.display()
            );
        }
    }
    Ok(())
}

/// An output folder made for one command: removed again, with what was written into
/// it, unless the command ends well ([`CreatedDir::keep`]), so a failure leaves no
/// empty or half-filled folder behind. A folder that existed before is left alone.
pub struct CreatedDir {
    /// The first folder of the path that did not exist (what is removed), if any, and
    /// its identity when made: a folder put in its place since is not removed.
    made: Option<(std::path::PathBuf, Option<(u64, u64)>)>,
}

/// A path's (device, inode), to tell a folder from one put in its place.
pub fn identity(p: &Path) -> Option<(u64, u64)> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        std::fs::symlink_metadata(p)
            .ok()
            .map(|m| (m.dev(), m.ino()))
    }
    #[cfg(not(unix))]
    {
        let _ = p;
        None
    }
}

/// Removes `dir` (and what is in it) if it is still the folder of `id`.
pub fn remove_if_same(dir: &Path, id: Option<(u64, u64)>) {
    if id.is_some() && identity(dir) == id {
        let _ = std::fs::remove_dir_all(dir);
    }
}

/// The first folder of `dir`'s path that does not exist (what making `dir` creates
/// first), if any.
pub fn missing_root(dir: &Path) -> Option<std::path::PathBuf> {
    let mut made = None;
    let mut p = Some(dir);
    while let Some(d) = p.filter(|d| !d.as_os_str().is_empty() && !d.exists()) {
        made = Some(d.to_path_buf());
        p = d.parent();
    }
    made
}

/// Makes `dir` and its missing parents ([`CreatedDir`]).
pub fn create_dir(dir: &Path) -> anyhow::Result<CreatedDir> {
    let made = missing_root(dir);
    std::fs::create_dir_all(dir)
        .map_err(|e| anyhow::anyhow!("cannot create the folder {}: {e}", dir.display()))?;
    Ok(CreatedDir {
        made: made.map(|m| {
            let id = identity(&m);
            (m, id)
        }),
    })
}

impl CreatedDir {
    /// The command ended well: the folder stays.
    pub fn keep(mut self) {
        self.made = None;
    }
}

impl Drop for CreatedDir {
    fn drop(&mut self) {
        if let Some((d, id)) = self.made.take() {
            remove_if_same(&d, id);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rule<'a>(inputs: &'a [(&'a str, &'a Path)]) -> OutputFile<'a> {
        OutputFile {
            flag: "--out",
            what: "the mesh",
            extensions: &["ply", "glb"],
            inputs,
        }
    }

    #[test]
    fn refuses_what_it_must_and_allows_the_rest() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        // A run directory and a file being read.
        let run = d.join("run");
        std::fs::create_dir(&run).unwrap();
        std::fs::write(run.join("stats.jsonl"), "").unwrap();
        std::fs::write(run.join("model.safetensors"), "m").unwrap();
        let model = d.join("m.safetensors");
        std::fs::write(&model, "m").unwrap();
        let inputs = [("the model", model.as_path())];
        let ok = |p: &Path| check_file(p, &rule(&inputs));
        assert!(ok(&d.join("a.ply")).is_ok());
        assert!(ok(&d.join("A.GLB")).is_ok());
        assert!(ok(&run.join("mesh.ply")).is_ok());
        let e = ok(&d.join("a.txt")).unwrap_err().to_string();
        assert!(e.contains(".ply or .glb"), "{e}");
        assert!(ok(&d.join("noext")).is_err());
        assert!(ok(d).unwrap_err().to_string().contains("directory"));
        // A run's own file, whatever the extension rule says.
        let any = OutputFile {
            extensions: &["png", "json", "safetensors"],
            ..rule(&[])
        };
        for name in ["training.png", "config.json", "optimizer.safetensors"] {
            let e = check_file(&run.join(name), &any).unwrap_err().to_string();
            assert!(e.contains("would replace the run's own"), "{name}: {e}");
        }
        // Not a run: the same names are free.
        assert!(check_file(&d.join("config.json"), &any).is_ok());
        // The file being read, also through a symlink and a hard link.
        let both = OutputFile {
            extensions: &["safetensors"],
            inputs: &inputs,
            ..rule(&[])
        };
        let other = d.join("other");
        std::fs::create_dir(&other).unwrap();
        std::os::unix::fs::symlink(&model, other.join("link.safetensors")).unwrap();
        std::fs::hard_link(&model, other.join("hard.safetensors")).unwrap();
        for p in [
            other.join("link.safetensors"),
            other.join("hard.safetensors"),
        ] {
            let e = check_file(&p, &both).unwrap_err().to_string();
            assert!(e.contains("is the model"), "{}: {e}", p.display());
        }
        // Inside a folder being read.
        let data = [("the dataset", other.as_path())];
        let e = check_file(&other.join("m.ply"), &rule(&data))
            .unwrap_err()
            .to_string();
        assert!(e.contains("is inside the dataset"), "{e}");
        // A FIFO is written in place, whatever its name.
        let fifo = d.join("pipe");
        let made = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap();
        assert!(made.success());
        assert_eq!(
            check_file(&fifo, &rule(&[])).unwrap(),
            OutputTarget::Stream(fifo.clone())
        );
    }

    #[test]
    fn output_folders() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let run = d.join("run");
        std::fs::create_dir(&run).unwrap();
        std::fs::write(run.join(".lock"), "").unwrap();
        let data = d.join("data");
        std::fs::create_dir(&data).unwrap();
        std::fs::write(d.join("file"), "").unwrap();
        let inputs = [("the dataset", data.as_path())];
        assert!(check_dir(&d.join("renders"), &inputs).is_ok());
        assert!(check_dir(&run.join("renders"), &inputs).is_ok());
        for bad in [run.clone(), data.join("test"), data.clone(), d.join("file")] {
            assert!(check_dir(&bad, &inputs).is_err(), "{}", bad.display());
        }
    }

    #[test]
    fn a_made_folder_goes_unless_kept() {
        let dir = tempfile::tempdir().unwrap();
        let nested = dir.path().join("a/b");
        let made = create_dir(&nested).unwrap();
        std::fs::write(nested.join("frame.png"), "x").unwrap();
        drop(made);
        assert!(!dir.path().join("a").exists());
        create_dir(&nested).unwrap().keep();
        assert!(nested.is_dir());
        // A folder put in the made one's place is not removed.
        let made = create_dir(&nested).unwrap();
        let top = dir.path().join("a");
        std::fs::remove_dir_all(&top).unwrap();
        std::fs::create_dir_all(top.join("other")).unwrap();
        drop(made);
        assert!(top.join("other").is_dir());
        std::fs::remove_dir_all(&top).unwrap();
        create_dir(&nested).unwrap().keep();
        // An existing folder is never removed.
        std::fs::write(nested.join("mine"), "x").unwrap();
        drop(create_dir(&nested).unwrap());
        assert!(nested.join("mine").is_file());
    }
}
