//! Lifting 2D to 3D (paper §3.2.4, Fig. 1c): anything predicted per pixel in the
//! training views — labels, masks, foundation-model features — fused into the voxels
//! and rendered from any view.
//!
//! - Fusion ([`Fuser`]): per view, each voxel accumulates Σ w·value and Σ w over the
//!   pixels whose rays it contributes to, w = its blending weight T·α in that ray. That
//!   sum is the transpose of compositing, which the training backward already computes:
//!   with a value image as the gradient of the rendered colour, the backward's colour
//!   gradient of a voxel is exactly Σ_pixels w·value (same frame, same depth order,
//!   same supersampling and its transposed filter). Three channels per backward.
//! - A [`Field`] holds per voxel the weighted mean (labels: per-class probabilities) and
//!   Σ w, and is stored as safetensors ([`Field::save`], [`Field::load`]).
//! - Rendering ([`render_field`]): the field's channels composited in place of colour
//!   ([`crate::raster::Renderer::set_voxel_colours`]), three per frame, over nothing;
//!   [`Field::labels_of`] turns a rendered label field into class values,
//!   [`Pca`] a feature field into colours.

mod fuse;
mod io;
mod pca;
mod render;

pub use fuse::Fuser;
pub use io::F16_FROM;
pub use pca::Pca;
pub use render::{render_field, FieldGpu, FieldImage};

use crate::error::{Error, Result};
use crate::scene::Scene;

/// Most channels a field may have (the fusion's sums take 4 bytes per voxel and
/// channel on the device; one backward per three channels and view).
pub const MAX_CHANNELS: u32 = 1024;

/// What a field's channels mean.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum FieldKind {
    /// One channel per class: the class's 8-bit label value in the source images,
    /// ascending; a voxel's channels are its class probabilities.
    Labels(Vec<u8>),
    /// Real-valued features (any number of channels).
    Features,
}

/// A field on the voxels of one model.
#[derive(Clone, Debug, PartialEq)]
pub struct Field {
    pub kind: FieldKind,
    pub voxels: u32,
    pub channels: u32,
    /// Per voxel, `channels` values (voxel-major): Σ w·value / Σ w, 0 where Σ w = 0.
    pub values: Vec<f32>,
    /// Per voxel, Σ w over every fused pixel (the evidence behind its values).
    pub weights: Vec<f32>,
    /// [`model_id`] of the model it was fused on.
    pub model_id: u64,
    /// Free-form provenance stored with it (split, source folder, views, ...).
    pub meta: std::collections::BTreeMap<String, String>,
}

/// Identity of a model's voxel layout (FNV-1a of its octpaths and levels): a field fits
/// only the model it was fused on.
pub fn model_id(scene: &Scene) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |b: u8| {
        h ^= u64::from(b);
        h = h.wrapping_mul(0x0100_0000_01b3);
    };
    for p in &scene.octpath {
        p.to_le_bytes().into_iter().for_each(&mut eat);
    }
    scene.octlevel.iter().for_each(|&l| eat(l));
    h
}

/// Refuses a channel count outside 1..=[`MAX_CHANNELS`].
pub fn check_channels(channels: u32) -> Result<()> {
    if channels == 0 || channels > MAX_CHANNELS {
        return Err(Error::Invalid(format!(
            "a field has 1 to {MAX_CHANNELS} channels, not {channels}"
        )));
    }
    Ok(())
}

impl Field {
    /// Refuses a model other than the one the field was fused on.
    pub fn check_model(&self, scene: &Scene) -> Result<()> {
        let id = model_id(scene);
        if self.voxels as usize != scene.num_voxels() || self.model_id != id {
            return Err(Error::Invalid(format!(
                "the field was fused on another model ({} voxels, layout {:016x}) than this \
                 one ({} voxels, layout {id:016x}): fuse it again with this model",
                self.voxels,
                self.model_id,
                scene.num_voxels()
            )));
        }
        Ok(())
    }

    /// A field from the fused sums: `sums` planar `[channels][voxels]`, `weights` Σ w
    /// per voxel.
    pub fn from_sums(
        kind: FieldKind,
        channels: u32,
        sums: &[f32],
        weights: &[f32],
        model_id: u64,
    ) -> Result<Field> {
        let n = weights.len();
        if sums.len() != channels as usize * n {
            return Err(Error::Invalid(format!(
                "field sums: {} values for {channels} channels of {n} voxels",
                sums.len()
            )));
        }
        if let FieldKind::Labels(c) = &kind {
            if c.len() != channels as usize {
                return Err(Error::Invalid(format!(
                    "field sums: {} classes for {channels} channels",
                    c.len()
                )));
            }
        }
        let c = channels as usize;
        let mut values = vec![0f32; n * c];
        for (v, &w) in weights.iter().enumerate() {
            if w > 0.0 {
                for ch in 0..c {
                    values[v * c + ch] = sums[ch * n + v] / w;
                }
            }
        }
        Ok(Field {
            kind,
            voxels: n as u32,
            channels,
            values,
            weights: weights.to_vec(),
            model_id,
            meta: Default::default(),
        })
    }

    /// The class values of a rendered label field: per pixel the arg-max of the
    /// composited class probabilities, with the background (the transmittance 1 − α
    /// left behind the last voxel) counted for class index 0 — so pixels with no
    /// surface get the first class (the 0 of a {0, 255} mask); ties go to the lower
    /// class. Also returns the probabilities with that background mass, pixel-major.
    pub fn labels_of(&self, img: &FieldImage) -> Result<(Vec<u8>, Vec<f32>)> {
        let FieldKind::Labels(classes) = &self.kind else {
            return Err(Error::Invalid(
                "labels_of needs a label field, this one holds features".into(),
            ));
        };
        if img.channels != self.channels {
            return Err(Error::Invalid(format!(
                "a {}-channel image of a {}-channel field",
                img.channels, self.channels
            )));
        }
        let c = self.channels as usize;
        let mut probs = img.values.clone();
        let mut labels = Vec::with_capacity(img.alpha.len());
        for (i, a) in img.alpha.iter().enumerate() {
            let p = &mut probs[i * c..(i + 1) * c];
            p[0] += 1.0 - a;
            let mut best = 0;
            for k in 1..c {
                if p[k] > p[best] {
                    best = k;
                }
            }
            labels.push(classes[best]);
        }
        Ok((labels, probs))
    }

    /// Device bytes the fusion of `channels` channels on `voxels` voxels holds for its
    /// sums (one plane per channel and one for Σ w).
    pub fn fusion_bytes(voxels: u32, channels: u32) -> u64 {
        (u64::from(channels) + 1) * u64::from(voxels) * 4
    }
}
