//! Rendering a field: its channels composited in place of colour, three per frame.

use super::Field;
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::gpu::{Buffer, Context};
use crate::raster::{RenderOptions, Renderer, VoxelColours};
use crate::scene::SceneGpu;

/// A field on the device (voxel-major f32), for [`render_field`] or for recording
/// frames with [`Renderer::set_voxel_colours`] into a host's own command buffers.
pub struct FieldGpu {
    buffer: Buffer,
    channels: u32,
    voxels: u32,
}

impl FieldGpu {
    /// Uploads `field`'s per-voxel values.
    pub fn upload(ctx: &Context, field: &Field) -> Result<FieldGpu> {
        let data: &[f32] = if field.values.is_empty() {
            &[0.0]
        } else {
            &field.values
        };
        Ok(FieldGpu {
            buffer: ctx.buffer_from("field.values", data)?,
            channels: field.channels,
            voxels: field.voxels,
        })
    }

    /// Channels per voxel.
    pub fn channels(&self) -> u32 {
        self.channels
    }

    /// Device address of the values.
    pub fn address(&self) -> u64 {
        self.buffer.address()
    }

    /// The three channels from `first` as a renderer's colour source.
    pub fn colours(&self, first: u32) -> VoxelColours {
        VoxelColours {
            address: self.buffer.address(),
            channels: self.channels,
            first,
        }
    }
}

/// A rendered field at a camera's size.
#[derive(Clone, Debug, PartialEq)]
pub struct FieldImage {
    pub width: u32,
    pub height: u32,
    pub channels: u32,
    /// Pixel-major `[height·width][channels]`: Σ_k T_k α_k f_k (no background).
    pub values: Vec<f32>,
    /// Opacity 1 − T per pixel.
    pub alpha: Vec<f32>,
}

/// Renders every channel of `field` for `cam` (⌈channels/3⌉ frames, the renderer's
/// colour source restored afterwards).
pub fn render_field(
    r: &mut Renderer,
    scene: &SceneGpu,
    field: &FieldGpu,
    cam: &Camera,
    opts: &RenderOptions,
) -> Result<FieldImage> {
    if field.voxels != scene.voxels {
        return Err(Error::Invalid(format!(
            "a field of {} voxels for a scene of {}",
            field.voxels, scene.voxels
        )));
    }
    let c = field.channels as usize;
    let mut out: Option<FieldImage> = None;
    for first in (0..field.channels).step_by(3) {
        r.set_voxel_colours(Some(field.colours(first)));
        let frame = r.render(scene, cam, opts);
        r.set_voxel_colours(None);
        let (img, _) = frame?;
        let np = img.alpha.len();
        let o = out.get_or_insert_with(|| FieldImage {
            width: img.width,
            height: img.height,
            channels: field.channels,
            values: vec![0.0; np * c],
            alpha: img.alpha.clone(),
        });
        for (i, rgb) in img.rgb.iter().enumerate() {
            for (k, v) in rgb.iter().enumerate() {
                let ch = first as usize + k;
                if ch < c {
                    o.values[i * c + ch] = *v;
                }
            }
        }
    }
    out.ok_or_else(|| Error::Invalid("a field without channels".into()))
}
