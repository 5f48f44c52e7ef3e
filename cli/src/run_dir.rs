//! The run directory of `svraster train`: its lock, the checkpoint pair
//! (model.safetensors + optimizer.safetensors) written so that a failure never loses the last
//! good one, the log truncation on resume, and the stop signals.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU32, Ordering};

use anyhow::{bail, Context as _};
use svraster::scene::checkpoint;
use svraster::train::trainer::Trainer;

/// Stop requests (Ctrl-C, SIGTERM, SIGHUP) since the training loop started.
pub(super) static INTERRUPTS: AtomicU32 = AtomicU32::new(0);

/// Routes Ctrl-C and SIGTERM/SIGHUP (what `timeout`, `kill`, Slurm, systemd and
/// `docker stop` send) to a counter the training loop polls: the first request is
/// acknowledged at once and the run saves and stops after the current step (an adaptive
/// step included); a second one exits at once without saving (status 130).
pub(super) fn catch_signals() -> anyhow::Result<()> {
    static INSTALLED: std::sync::OnceLock<Result<(), String>> = std::sync::OnceLock::new();
    INSTALLED
        .get_or_init(|| {
            ctrlc::set_handler(|| {
                if INTERRUPTS.fetch_add(1, Ordering::SeqCst) == 0 {
                    eprintln!(
                        "\nstopping after this step and saving … (again to exit without saving)"
                    );
                } else {
                    eprintln!("\nexiting without saving");
                    std::process::exit(130);
                }
            })
            .map_err(|e| e.to_string())
        })
        .clone()
        .map_err(|e| anyhow::anyhow!("cannot install the Ctrl-C/SIGTERM handler: {e}"))
}

/// A run directory locked by this process ([`lock_run`]): the advisory lock on
/// `run/.lock`, released when this is dropped or the process dies.
pub(super) struct RunLock {
    file: std::fs::File,
    path: PathBuf,
    run: PathBuf,
}

/// Locks `run` (an existing directory) for this process: a second `train`/`demo` into the
/// same directory fails at once instead of mixing two runs.
pub(super) fn lock_run(run: &Path) -> anyhow::Result<RunLock> {
    let path = run.join(".lock");
    let f = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&path)
        .with_context(|| format!("cannot open the run lock {}", path.display()))?;
    match f.try_lock() {
        Ok(()) => Ok(RunLock {
            file: f,
            path,
            run: run.to_path_buf(),
        }),
        Err(std::fs::TryLockError::WouldBlock) => bail!(
            "{} is in use: another svraster process is training in it; wait for it to \
             finish (or stop it), or choose another --out",
            run.display()
        ),
        Err(std::fs::TryLockError::Error(e)) => {
            bail!("cannot lock {}: {e}", path.display())
        }
    }
}

impl RunLock {
    /// Whether `run/.lock` is still the file this process locked: false once the run
    /// directory was removed, moved or replaced (removed and made again, say by another
    /// run into the same --out) while this process held it.
    fn held(&self) -> bool {
        let Ok(now) = std::fs::metadata(&self.path) else {
            return false;
        };
        #[cfg(unix)]
        {
            use std::os::unix::fs::MetadataExt;
            match self.file.metadata() {
                // A removed lock file has no links left (and its inode number may be
                // reused by a new file at the same path).
                Ok(ours) => ours.nlink() > 0 && ours.dev() == now.dev() && ours.ino() == now.ino(),
                Err(_) => false,
            }
        }
        #[cfg(not(unix))]
        {
            // Elsewhere a directory with open files in it cannot be removed or moved.
            now.is_file()
        }
    }

    /// Fails, naming the directory and what to do, when the run directory is no longer
    /// the one this process locked ([`RunLock::held`]): a run then stops without writing
    /// anything more, so that it never mixes with whatever is at that path now.
    pub(super) fn check(&self, iter: u32) -> anyhow::Result<()> {
        if self.held() {
            return Ok(());
        }
        bail!(
            "the run directory {} was removed, moved or replaced while this run trained \
             (now at iteration {iter}): stopped without writing to it, so that nothing mixes \
             with what is there now. A moved run continues from its last checkpoint with \
             --resume and --out at its new place; otherwise start the run again",
            self.run.display()
        )
    }
}

use std::collections::HashMap;

use safetensors::{tensor::TensorView, Dtype, SafeTensors};
use svraster::fsio::{sync_dir, tmp_path, write_synced};

/// Writes `bytes` to `path` atomically ([`svraster::fsio::write_atomic`]).
pub(super) fn atomic_write(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    Ok(svraster::fsio::write_atomic(path, bytes)?)
}

pub(super) fn fnv64(bytes: &[u8]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

/// The optimizer state's file in a run directory: a safetensors file holding the Adam
/// moments (`geo.m`, `geo.v`, `sh0.m`, `sh0.v`, `shs.m`, `shs.v`, F32, one dimension) with
/// `format`, `iteration` and `model_fnv64` (hash of the model file it belongs to) in its
/// metadata.
pub(super) const OPT_FILE: &str = "optimizer.safetensors";
/// The optimizer state's file of versions before safetensors (not resumable).
const OLD_OPT_FILE: &str = "optimizer.bin";
const OPT_FORMAT: &str = "svraster-vk-optimizer/1";
const OPT_TENSORS: [&str; 6] = ["geo.m", "geo.v", "sh0.m", "sh0.v", "shs.m", "shs.v"];

/// The optimizer file's bytes: `state` (in [`OPT_TENSORS`] order) after `iter`
/// iterations, for the model file `model`.
fn optimizer_bytes(iter: u32, model: &[u8], state: &[Vec<f32>]) -> anyhow::Result<Vec<u8>> {
    anyhow::ensure!(
        state.len() == OPT_TENSORS.len(),
        "optimizer state of {} groups",
        state.len()
    );
    let bytes: Vec<Vec<u8>> = state
        .iter()
        .map(|s| s.iter().flat_map(|v| v.to_le_bytes()).collect())
        .collect();
    let views = OPT_TENSORS
        .iter()
        .zip(&bytes)
        .map(|(name, b)| Ok((*name, TensorView::new(Dtype::F32, vec![b.len() / 4], b)?)))
        .collect::<Result<Vec<_>, safetensors::SafeTensorError>>()?;
    let meta = HashMap::from([
        ("format".to_string(), OPT_FORMAT.to_string()),
        ("iteration".to_string(), iter.to_string()),
        ("model_fnv64".to_string(), format!("{:016x}", fnv64(model))),
    ]);
    sorted_header(safetensors::serialize(views, Some(meta))?)
}

/// `bytes` (a safetensors file) with its JSON header's keys in sorted order, the
/// `__metadata__` entries too, padded with spaces to the same length: the crate writes
/// the metadata in its HashMap's per-process random order, so two identical states
/// would otherwise give different files (`--deterministic` promises identical bytes).
fn sorted_header(mut bytes: Vec<u8>) -> anyhow::Result<Vec<u8>> {
    use std::collections::BTreeMap;
    anyhow::ensure!(
        bytes.len() >= 8,
        "safetensors output of {} bytes",
        bytes.len()
    );
    let n = u64::from_le_bytes(bytes[..8].try_into().expect("8 bytes")) as usize;
    anyhow::ensure!(8 + n <= bytes.len(), "safetensors header past the end");
    let header: BTreeMap<String, serde_json::Value> = serde_json::from_slice(&bytes[8..8 + n])?;
    let mut out = String::from("{");
    for (i, (k, v)) in header.iter().enumerate() {
        if i > 0 {
            out.push(',');
        }
        out.push_str(&serde_json::to_string(k)?);
        out.push(':');
        if k == "__metadata__" {
            let meta: BTreeMap<String, String> = serde_json::from_value(v.clone())?;
            out.push_str(&serde_json::to_string(&meta)?);
        } else {
            out.push_str(&serde_json::to_string(v)?);
        }
    }
    out.push('}');
    anyhow::ensure!(out.len() <= n, "sorted safetensors header grew");
    let dst = &mut bytes[8..8 + n];
    dst[..out.len()].copy_from_slice(out.as_bytes());
    dst[out.len()..].fill(b' ');
    Ok(bytes)
}

/// Writes the checkpoint pair model.safetensors + optimizer.safetensors (Adam moments,
/// iteration, hash of the model file) so that a failure at any point leaves a resumable pair: both
/// are written and flushed as `.tmp` files first (a full disk fails here, and the
/// previous pair stays as it was), then renamed, optimizer first. A crash between the two
/// renames leaves the new optimizer state beside `model.safetensors.tmp`, which
/// `--resume` recognises by its hash and completes.
pub(super) fn save_run(run: &Path, lock: &RunLock, trainer: &mut Trainer) -> anyhow::Result<()> {
    lock.check(trainer.iter())?;
    let scene = trainer.scene()?;
    let model = checkpoint::to_bytes(&scene)?;
    let state = trainer.optimizer_state()?;
    let opt = optimizer_bytes(trainer.iter(), &model, &state)?;
    let model_path = run.join("model.safetensors");
    let opt_path = run.join(OPT_FILE);
    let (model_tmp, opt_tmp) = (tmp_path(&model_path), tmp_path(&opt_path));
    let written = write_synced(&model_tmp, &model).and_then(|()| write_synced(&opt_tmp, &opt));
    if let Err(e) = written {
        let _ = std::fs::remove_file(&model_tmp);
        let _ = std::fs::remove_file(&opt_tmp);
        if model_path.exists() {
            bail!(
                "cannot write the checkpoint ({e}); the previous checkpoint in {} is \
                 unchanged and resumable (free space, then --resume)",
                run.display()
            );
        }
        bail!(
            "cannot write the first checkpoint ({e}): {} holds no checkpoint yet; free \
             space, then run the same command again (the run starts over)",
            run.display()
        );
    }
    std::fs::rename(&opt_tmp, &opt_path)
        .and_then(|()| std::fs::rename(&model_tmp, &model_path))
        .with_context(|| format!("cannot install the checkpoint in {}", run.display()))?;
    sync_dir(run);
    Ok(())
}

/// Reads the checkpoint pair for `--resume`: (model bytes, iteration, moments),
/// completing a save that stopped between its two renames (see [`save_run`]).
pub(super) fn load_pair(run: &Path) -> anyhow::Result<(Vec<u8>, u32, Vec<Vec<f32>>)> {
    let model_path = run.join("model.safetensors");
    let opt_path = run.join(OPT_FILE);
    if !opt_path.exists() && run.join(OLD_OPT_FILE).exists() {
        bail!(
            "cannot resume a run from an older version: {} holds {OLD_OPT_FILE}, whose \
             format this version no longer reads; start a new run (its model.safetensors \
             still evaluates and renders)",
            run.display()
        );
    }
    let (iter, hash, state) = load_optimizer(&opt_path)?;
    let model = std::fs::read(&model_path)
        .with_context(|| format!("cannot resume: cannot read {}", model_path.display()))?;
    if fnv64(&model) == hash {
        return Ok((model, iter, state));
    }
    let tmp = tmp_path(&model_path);
    if let Ok(pending) = std::fs::read(&tmp) {
        if fnv64(&pending) == hash {
            std::fs::rename(&tmp, &model_path)
                .with_context(|| format!("cannot complete the checkpoint {}", tmp.display()))?;
            eprintln!("completed the checkpoint of iteration {iter} that a stop interrupted");
            return Ok((pending, iter, state));
        }
    }
    if let Err(e) = svraster::scene::checkpoint::from_bytes(&model) {
        bail!(
            "{} is damaged ({e}): the checkpoint of iteration {iter} cannot be resumed; \
             restore the file from a copy of the run, or start a new run (another --out)",
            model_path.display()
        );
    }
    bail!(
        "{} does not match {} (saved together at iteration {iter}): one of the pair was \
         replaced or modified since; restore both from one save, or start a new run \
         (another --out)",
        model_path.display(),
        run.join(OPT_FILE).display()
    )
}

/// Drops the lines of `run/stats.jsonl` past iteration `iter` (a run that crashed after
/// its last checkpoint logged iterations the resumed run will log again): iteration
/// lines (`iter`), adaptive steps (`adapt.iter`) and held-out scores (`eval.iter`) past
/// it. Lines of other shapes stay. Lines that are not JSON (a write torn by a crash) are
/// dropped, and a warning says how many and where.
pub(super) fn truncate_stats(run: &Path, iter: u32) -> anyhow::Result<()> {
    let path = run.join("stats.jsonl");
    let Ok(text) = std::fs::read_to_string(&path) else {
        return Ok(());
    };
    let mut broken = Vec::new();
    let keep: Vec<&str> = text
        .lines()
        .enumerate()
        .filter(|(n, l)| {
            let Ok(v) = serde_json::from_str::<serde_json::Value>(l) else {
                if !l.trim().is_empty() {
                    broken.push(n + 1);
                }
                return false;
            };
            let at = v["iter"]
                .as_u64()
                .or_else(|| v["adapt"]["iter"].as_u64())
                .or_else(|| v["eval"]["iter"].as_u64());
            at.is_none_or(|i| i <= u64::from(iter))
        })
        .map(|(_, l)| l)
        .collect();
    if !broken.is_empty() {
        eprintln!(
            "warning: {} has {} line(s) that are not JSON (line {}; a write torn by a \
             crash?): dropped on resume",
            path.display(),
            broken.len(),
            broken
                .iter()
                .take(5)
                .map(|n| n.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    if keep.len() != text.lines().count() {
        let mut out = keep.join("\n");
        if !out.is_empty() {
            out.push('\n');
        }
        atomic_write(&path, out.as_bytes())?;
    }
    Ok(())
}

/// Reads the optimizer file: (iteration, model hash, moments).
pub(super) fn load_optimizer(path: &Path) -> anyhow::Result<(u32, u64, Vec<Vec<f32>>)> {
    let b = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let bad = |what: String| {
        anyhow::anyhow!(
            "{} is corrupt ({what}); resume from an intact run or start a new one",
            path.display()
        )
    };
    let (_, header) =
        SafeTensors::read_metadata(&b).map_err(|e| bad(format!("not a safetensors file: {e}")))?;
    let meta = header.metadata().clone().unwrap_or_default();
    let get = |k: &str| {
        meta.get(k)
            .ok_or_else(|| bad(format!("metadata `{k}` missing")))
    };
    if get("format")? != OPT_FORMAT {
        return Err(bad(format!(
            "format `{}`, not `{OPT_FORMAT}`",
            get("format")?
        )));
    }
    let iter: u32 = get("iteration")?
        .parse()
        .map_err(|_| bad("`iteration` is not an iteration count".into()))?;
    let hash = u64::from_str_radix(get("model_fnv64")?, 16)
        .map_err(|_| bad("`model_fnv64` is not a hex hash".into()))?;
    let tensors =
        SafeTensors::deserialize(&b).map_err(|e| bad(format!("not a safetensors file: {e}")))?;
    if tensors.len() != OPT_TENSORS.len() {
        return Err(bad(format!(
            "{} tensors, not {}",
            tensors.len(),
            OPT_TENSORS.len()
        )));
    }
    let mut out = Vec::new();
    for name in OPT_TENSORS {
        let t = tensors
            .tensor(name)
            .map_err(|_| bad(format!("tensor `{name}` missing")))?;
        if t.dtype() != Dtype::F32 || t.shape().len() != 1 {
            return Err(bad(format!("tensor `{name}` is not a 1-D F32 tensor")));
        }
        let v: Vec<f32> = t
            .data()
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
            .collect();
        if let Some(i) = v.iter().position(|x| !x.is_finite()) {
            return Err(bad(format!("tensor `{name}` holds {} at entry {i}", v[i])));
        }
        out.push(v);
    }
    Ok((iter, hash, out))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn optimizer_state_round_trips_and_bad_files_are_named() {
        let dir = tempfile::Builder::new()
            .prefix("svraster-opt-")
            .tempdir()
            .unwrap();
        let state: Vec<Vec<f32>> = (0..6)
            .map(|g| (0..g * 3).map(|i| i as f32 * 0.5 - 1e-30).collect())
            .collect();
        let model = b"model bytes".to_vec();
        let path = dir.path().join(OPT_FILE);
        std::fs::write(&path, optimizer_bytes(1234, &model, &state).unwrap()).unwrap();
        let (iter, hash, back) = load_optimizer(&path).unwrap();
        assert_eq!((iter, hash), (1234, fnv64(&model)));
        assert_eq!(back, state); // bit-exact, empty groups included
                                 // The same state gives the same bytes (the header's metadata sorted).
        let a = optimizer_bytes(1234, &model, &state).unwrap();
        assert!((0..8).all(|_| optimizer_bytes(1234, &model, &state).unwrap() == a));
        let n = u64::from_le_bytes(a[..8].try_into().unwrap()) as usize;
        let text = std::str::from_utf8(&a[8..8 + n]).unwrap();
        let (f, i, m) = (
            text.find("\"format\"").unwrap(),
            text.find("\"iteration\"").unwrap(),
            text.find("\"model_fnv64\"").unwrap(),
        );
        assert!(f < i && i < m, "{text}");

        // Another format, a missing tensor, junk: each a named error.
        let other = |meta: HashMap<String, String>, names: &[&str]| {
            let bytes: Vec<u8> = vec![0; 4];
            let views: Vec<_> = names
                .iter()
                .map(|n| (*n, TensorView::new(Dtype::F32, vec![1], &bytes).unwrap()))
                .collect();
            safetensors::serialize(views, Some(meta)).unwrap()
        };
        let meta = |format: &str| {
            HashMap::from([
                ("format".to_string(), format.to_string()),
                ("iteration".to_string(), "1".to_string()),
                ("model_fnv64".to_string(), "00ff".to_string()),
            ])
        };
        for (bytes, want) in [
            (other(meta("something-else/1"), &OPT_TENSORS), "format"),
            (other(meta(OPT_FORMAT), &OPT_TENSORS[..5]), "5 tensors"),
            (b"junk".to_vec(), "not a safetensors file"),
        ] {
            std::fs::write(&path, bytes).unwrap();
            let e = format!("{:#}", load_optimizer(&path).unwrap_err());
            assert!(e.contains(OPT_FILE) && e.contains(want), "{e}");
        }
        dir.close().unwrap();
    }

    /// Resuming at iteration 20 drops what the resumed run logs again: iteration,
    /// adaptive and held-out lines past 20, and lines that are not JSON (torn writes,
    /// with a warning). The held-out curve up to the checkpoint and lines of other shapes
    /// stay (eval lines were dropped).
    #[test]
    fn resume_keeps_the_log_up_to_the_checkpoint() {
        let dir = tempfile::tempdir().unwrap();
        let lines = [
            r#"{"iter":10,"loss":1}"#,
            r#"{"adapt":{"iter":15}}"#,
            r#"{"eval":{"iter":20,"psnr":30}}"#,
            r#"{"note":"no iteration"}"#,
            "not json {",
            r#"{"iter":30,"loss":1}"#,
            r#"{"adapt":{"iter":25}}"#,
            r#"{"eval":{"iter":30,"psnr":31}}"#,
        ];
        let path = dir.path().join("stats.jsonl");
        std::fs::write(&path, lines.join("\n") + "\n").unwrap();
        truncate_stats(dir.path(), 20).unwrap();
        let kept = std::fs::read_to_string(&path).unwrap();
        assert_eq!(kept, lines[..4].join("\n") + "\n");
        // Nothing past the checkpoint: the file is left as it is.
        truncate_stats(dir.path(), 20).unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), kept);
    }
}
