//! What several commands read: the model argument (a checkpoint or a run directory),
//! output names per frame, and paths made comparable (the output guard is
//! [`super::outputs`]).

use std::path::{Path, PathBuf};

use anyhow::bail;
use svraster::scene::{checkpoint, Scene};

/// A model argument: a `.safetensors` file, or a run directory holding `model.safetensors`.
pub fn model_path(model: &Path) -> anyhow::Result<PathBuf> {
    let p = if model.is_dir() {
        model.join("model.safetensors")
    } else {
        model.to_path_buf()
    };
    if !p.is_file() {
        bail!(
            "model {} not found: pass a .safetensors checkpoint, a run directory containing model.safetensors, or an SVRaster .pt",
            p.display()
        );
    }
    Ok(p)
}

/// A model: ours (`.safetensors`, plain or quantized), or SVRaster's `.pt` (imported with
/// the background and ss of the `config.yaml` SVRaster wrote beside it, else black and
/// ss 1.5; `svraster import` chooses them).
pub fn load_model(model: &Path) -> anyhow::Result<Scene> {
    use svraster::scene::svraster as svr;
    let p = model_path(model)?;
    if svr::is_torch_checkpoint(&p) {
        let opts = match svr::import_options_from_config(&p)? {
            Some((opts, config)) => {
                eprintln!(
                    "{}: an SVRaster checkpoint, read with the background and ss of {}",
                    p.display(),
                    config.display()
                );
                opts
            }
            None => {
                eprintln!(
                    "{}: an SVRaster checkpoint without its config.yaml, read with a black \
                     background and ss 1.5 (`svraster import --background \
                     white|black|frame-mean|R,G,B --ss S` to choose)",
                    p.display()
                );
                svr::SvrasterImport::default()
            }
        };
        return Ok(svr::import_svraster(&p, &opts)?);
    }
    Ok(checkpoint::load(&p)?)
}

/// Output names for frames: the frame's file stem, or `STEM_INDEX` (its index in the
/// split) where two frames share a stem, so that no output overwrites another.
pub fn output_names(names: &[&str]) -> Vec<String> {
    names
        .iter()
        .enumerate()
        .map(|(i, n)| {
            if names.iter().filter(|m| *m == n).count() > 1 {
                format!("{n}_{i}")
            } else {
                n.to_string()
            }
        })
        .collect()
}

/// `path` made absolute through its longest existing ancestor (symlinks resolved), so
/// that an output that does not exist yet can be compared with an input.
pub fn resolved(path: &Path) -> PathBuf {
    let mut tail = Vec::new();
    let mut p = path.to_path_buf();
    loop {
        if let Ok(c) = p.canonicalize() {
            return tail.iter().rev().fold(c, |acc: PathBuf, t| acc.join(t));
        }
        match (p.file_name().map(|f| f.to_os_string()), p.parent()) {
            (Some(f), Some(parent)) => {
                tail.push(f);
                p = if parent.as_os_str().is_empty() {
                    PathBuf::from(".")
                } else {
                    parent.to_path_buf()
                };
            }
            _ => return path.to_path_buf(),
        }
    }
}
