//! The run directory of `svraster train`: its lock, the checkpoint pair
//! (model.safetensors + optimizer.bin) written so that a failure never loses the last
//! good one, the log truncation on resume, and the stop signals.

use std::path::Path;
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

/// Locks `run` (an existing directory) for this process: an advisory lock on
/// `run/.lock`, released when the returned file is dropped or the process dies. A second
/// `train`/`demo` into the same directory fails at once instead of mixing two runs.
pub(super) fn lock_run(run: &Path) -> anyhow::Result<std::fs::File> {
    let path = run.join(".lock");
    let f = std::fs::OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&path)
        .with_context(|| format!("cannot open the run lock {}", path.display()))?;
    match f.try_lock() {
        Ok(()) => Ok(f),
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

pub(super) const OPT_MAGIC: &[u8; 8] = b"SVRVKOPT";

/// Writes the checkpoint pair model.safetensors + optimizer.bin (iteration, hash of the
/// model file, Adam moments) so that a failure at any point leaves a resumable pair: both
/// are written and flushed as `.tmp` files first (a full disk fails here, and the
/// previous pair stays as it was), then renamed, optimizer first. A crash between the two
/// renames leaves the new optimizer state beside `model.safetensors.tmp`, which
/// `--resume` recognises by its hash and completes.
pub(super) fn save_run(run: &Path, trainer: &mut Trainer) -> anyhow::Result<()> {
    let scene = trainer.scene()?;
    let model = checkpoint::to_bytes(&scene)?;
    let state = trainer.optimizer_state()?;
    let mut opt = Vec::new();
    opt.extend_from_slice(OPT_MAGIC);
    opt.extend_from_slice(&(trainer.iter() as u64).to_le_bytes());
    opt.extend_from_slice(&fnv64(&model).to_le_bytes());
    opt.extend_from_slice(&(state.len() as u64).to_le_bytes());
    for s in &state {
        opt.extend_from_slice(&(s.len() as u64).to_le_bytes());
        opt.extend_from_slice(bytemuck::cast_slice(s));
    }
    let model_path = run.join("model.safetensors");
    let opt_path = run.join("optimizer.bin");
    let (model_tmp, opt_tmp) = (tmp_path(&model_path), tmp_path(&opt_path));
    let written = write_synced(&model_tmp, &model).and_then(|()| write_synced(&opt_tmp, &opt));
    if let Err(e) = written {
        let _ = std::fs::remove_file(&model_tmp);
        let _ = std::fs::remove_file(&opt_tmp);
        bail!(
            "cannot write the checkpoint ({e}); the previous checkpoint in {} is \
             unchanged and resumable (free space, then --resume)",
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
    let (iter, hash, state) = load_optimizer(&run.join("optimizer.bin"))?;
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
    bail!(
        "{} and optimizer.bin are from different iterations; cannot resume safely",
        model_path.display()
    )
}

/// Drops the lines of `run/stats.jsonl` past iteration `iter` (a run that crashed after
/// its last checkpoint logged iterations the resumed run will log again).
pub(super) fn truncate_stats(run: &Path, iter: u32) -> anyhow::Result<()> {
    let path = run.join("stats.jsonl");
    let Ok(text) = std::fs::read_to_string(&path) else {
        return Ok(());
    };
    let keep: Vec<&str> = text
        .lines()
        .filter(|l| {
            let v: serde_json::Value = serde_json::from_str(l).unwrap_or_default();
            let at = v["iter"].as_u64().or_else(|| v["adapt"]["iter"].as_u64());
            at.is_some_and(|i| i <= u64::from(iter))
        })
        .collect();
    if keep.len() != text.lines().count() {
        let mut out = keep.join("\n");
        if !out.is_empty() {
            out.push('\n');
        }
        atomic_write(&path, out.as_bytes())?;
    }
    Ok(())
}

/// Reads optimizer.bin: (iteration, model hash, moments).
pub(super) fn load_optimizer(path: &Path) -> anyhow::Result<(u32, u64, Vec<Vec<f32>>)> {
    let b = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let corrupt = || anyhow::anyhow!("{} is corrupt or truncated", path.display());
    let u64_at = |o: usize| -> anyhow::Result<u64> {
        Ok(u64::from_le_bytes(
            b.get(o..o + 8)
                .ok_or_else(corrupt)?
                .try_into()
                .expect("8 bytes"),
        ))
    };
    if b.get(..8) != Some(OPT_MAGIC.as_slice()) {
        bail!("{} is not an svraster optimizer state", path.display());
    }
    let iter = u64_at(8)?;
    let hash = u64_at(16)?;
    let n = u64_at(24)?;
    if n != 6 || iter > u32::MAX as u64 {
        return Err(corrupt());
    }
    let mut o = 32;
    let mut out = Vec::new();
    for _ in 0..n {
        let len = u64_at(o)? as usize;
        o += 8;
        let bytes = b
            .get(o..o + len.checked_mul(4).ok_or_else(corrupt)?)
            .ok_or_else(corrupt)?;
        out.push(
            bytes
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
                .collect(),
        );
        o += len * 4;
    }
    if o != b.len() {
        return Err(corrupt());
    }
    Ok((iter as u32, hash, out))
}
