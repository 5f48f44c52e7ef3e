//! Field files: safetensors (the `safetensors` crate), readable from Python.
//!
//! Tensors: `values` [voxels, channels] (F32, or F16 for feature fields of
//! [`F16_FROM`] channels or more), `weights` [voxels] F32 (Σ w), for label fields
//! `classes` [channels] U8 (each class's 8-bit value). Metadata: `format`
//! = `svraster-vk-field/1`, `kind` = `labels` | `features`, `model` = the model's layout
//! id (16 hex digits), and the field's own provenance keys.

use std::collections::HashMap;
use std::path::Path;

use safetensors::tensor::TensorView;
use safetensors::{Dtype, SafeTensors};

use super::{check_channels, Field, FieldKind};
use crate::error::{Error, Result};

/// Feature fields with at least this many channels are stored as f16.
pub const F16_FROM: u32 = 16;
const FORMAT: &str = "svraster-vk-field/1";

impl Field {
    /// The file's bytes.
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        let n = self.voxels as usize;
        let c = self.channels as usize;
        let half = self.kind == FieldKind::Features && self.channels >= F16_FROM;
        let values: Vec<u8> = if half {
            self.values
                .iter()
                .flat_map(|&v| half::f16::from_f32(v).to_le_bytes())
                .collect()
        } else {
            bytemuck::cast_slice(&self.values).to_vec()
        };
        let weights: &[u8] = bytemuck::cast_slice(&self.weights);
        let classes = match &self.kind {
            FieldKind::Labels(c) => c.clone(),
            FieldKind::Features => Vec::new(),
        };
        let bad = |e: safetensors::SafeTensorError| Error::Invalid(format!("field file: {e}"));
        let dtype = if half { Dtype::F16 } else { Dtype::F32 };
        let mut views = vec![
            (
                "values",
                TensorView::new(dtype, vec![n, c], &values).map_err(bad)?,
            ),
            (
                "weights",
                TensorView::new(Dtype::F32, vec![n], weights).map_err(bad)?,
            ),
        ];
        if !classes.is_empty() {
            views.push((
                "classes",
                TensorView::new(Dtype::U8, vec![classes.len()], &classes).map_err(bad)?,
            ));
        }
        let mut meta: HashMap<String, String> = self
            .meta
            .iter()
            .map(|(k, v)| (k.clone(), v.clone()))
            .collect();
        meta.insert("format".into(), FORMAT.into());
        let kind = match self.kind {
            FieldKind::Labels(_) => "labels",
            FieldKind::Features => "features",
        };
        meta.insert("kind".into(), kind.into());
        meta.insert("model".into(), format!("{:016x}", self.model_id));
        safetensors::serialize(views, Some(meta)).map_err(bad)
    }

    /// Writes the field to `path` atomically.
    pub fn save(&self, path: &Path) -> Result<()> {
        crate::fsio::write_atomic(path, &self.to_bytes()?)
    }

    /// Reads a field file, checking everything; errors name the file and the entry.
    pub fn load(path: &Path) -> Result<Field> {
        let bytes = std::fs::read(path).map_err(|error| Error::Io {
            path: path.display().to_string(),
            error,
        })?;
        Self::from_bytes(&bytes)
            .map_err(|e| Error::Invalid(format!("{}: {e}; fuse it again", path.display())))
    }

    /// Parses a field file's bytes (see [`Field::load`]).
    pub fn from_bytes(bytes: &[u8]) -> std::result::Result<Field, String> {
        let (_, header) = SafeTensors::read_metadata(bytes)
            .map_err(|e| format!("not a safetensors file ({e})"))?;
        let meta = header.metadata().clone().unwrap_or_default();
        if meta.get("format").map(String::as_str) != Some(FORMAT) {
            return Err(format!(
                "not a field file (metadata `format` is {:?}, not {FORMAT:?})",
                meta.get("format")
            ));
        }
        let st = SafeTensors::deserialize(bytes).map_err(|e| format!("malformed ({e})"))?;
        let values = st
            .tensor("values")
            .map_err(|e| format!("tensor `values`: {e}"))?;
        let weights = st
            .tensor("weights")
            .map_err(|e| format!("tensor `weights`: {e}"))?;
        let (n, c) = match values.shape() {
            [n, c] => (*n, *c),
            s => {
                return Err(format!(
                    "tensor `values` has shape {s:?}, not [voxels, channels]"
                ))
            }
        };
        let channels = u32::try_from(c).map_err(|_| format!("{c} channels"))?;
        check_channels(channels).map_err(|e| format!("tensor `values`: {e}"))?;
        let voxels = u32::try_from(n).map_err(|_| format!("{n} voxels"))?;
        let vals: Vec<f32> = match values.dtype() {
            Dtype::F32 => values
                .data()
                .chunks_exact(4)
                .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
                .collect(),
            Dtype::F16 => values
                .data()
                .chunks_exact(2)
                .map(|b| half::f16::from_le_bytes([b[0], b[1]]).to_f32())
                .collect(),
            d => return Err(format!("tensor `values` is {d:?}, not F32 or F16")),
        };
        if weights.dtype() != Dtype::F32 || weights.shape() != [n] {
            return Err(format!(
                "tensor `weights` is {:?} {:?}, not F32 [{n}]",
                weights.dtype(),
                weights.shape()
            ));
        }
        let wts: Vec<f32> = weights
            .data()
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        if let Some(i) = vals.iter().position(|v| !v.is_finite()) {
            return Err(format!("tensor `values`: entry {i} is {}", vals[i]));
        }
        if let Some(i) = wts.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
            return Err(format!("tensor `weights`: entry {i} is {}", wts[i]));
        }
        let kind = match meta.get("kind").map(String::as_str) {
            Some("features") => FieldKind::Features,
            Some("labels") => {
                let cl = st
                    .tensor("classes")
                    .map_err(|e| format!("tensor `classes`: {e}"))?;
                if cl.dtype() != Dtype::U8 || cl.shape() != [c] {
                    return Err(format!(
                        "tensor `classes` is {:?} {:?}, not U8 [{c}]",
                        cl.dtype(),
                        cl.shape()
                    ));
                }
                let classes = cl.data().to_vec();
                if classes.windows(2).any(|w| w[0] >= w[1]) {
                    return Err("tensor `classes` is not strictly ascending".into());
                }
                FieldKind::Labels(classes)
            }
            k => {
                return Err(format!(
                    "metadata `kind` is {k:?}, not \"labels\" or \"features\""
                ))
            }
        };
        let model_id = meta
            .get("model")
            .and_then(|m| u64::from_str_radix(m, 16).ok())
            .ok_or("metadata `model` is missing or not hexadecimal")?;
        let meta = meta
            .into_iter()
            .filter(|(k, _)| !["format", "kind", "model"].contains(&k.as_str()))
            .collect();
        Ok(Field {
            kind,
            voxels,
            channels,
            values: vals,
            weights: wts,
            model_id,
            meta,
        })
    }
}
