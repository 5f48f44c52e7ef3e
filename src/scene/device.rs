//! A scene's parameters on the device: the buffers the rasterizer reads and the trainer
//! updates, uploaded from and downloaded into a [`Scene`].

use crate::error::{Error, Result};
use crate::gpu::{Buffer, Context};
use crate::scene::{shs_device_len, shs_from_device, shs_to_device, Scene};

/// Uploads per-voxel SH values (`n` voxels × `w`, host layout `[N][w]`) into `buf` in
/// the blocked device layout ([`crate::scene::SHS_BLOCK`]).
pub(crate) fn upload_shs(
    ctx: &Context,
    buf: &Buffer,
    host: &[f32],
    n: usize,
    w: usize,
) -> Result<()> {
    if host.len() != n * w {
        return Err(Error::Invalid(format!(
            "{} SH values for {n} voxels of {w} each",
            host.len()
        )));
    }
    ctx.upload(buf, 0, &shs_to_device(host, n, w))
}

/// Downloads `n` voxels × `w` SH values from `buf` (blocked device layout) in the host
/// layout `[N][w]`.
pub(crate) fn download_shs(ctx: &Context, buf: &Buffer, n: usize, w: usize) -> Result<Vec<f32>> {
    let dev: Vec<f32> = ctx.download(buf, 0, shs_device_len(n, w))?;
    Ok(shs_from_device(&dev, n, w))
}

/// A scene's parameters on the device.
pub struct SceneGpu {
    pub(crate) octpath: Buffer,
    pub(crate) level: Buffer,
    pub(crate) corners: Buffer,
    pub(crate) geo: Buffer,
    pub(crate) sh0: Buffer,
    /// In the blocked device layout ([`crate::scene::SHS_BLOCK`]).
    pub(crate) shs: Buffer,
    pub voxels: u32,
    pub grid_points: u32,
    pub max_level: u32,
    /// Active SH degree (≤ the stored degree; training raises it progressively).
    pub sh_degree: u32,
    /// SH coefficients stored per voxel besides the DC term, `(D+1)² − 1` of the stored
    /// degree D.
    pub shs_per_voxel: u32,
    pub center: [f32; 3],
    pub extent: f32,
    pub background: [f32; 3],
    /// [`crate::scene::Scene::background_frame_mean`].
    pub background_frame_mean: bool,
}

impl SceneGpu {
    /// Validates and uploads a scene.
    pub fn upload(ctx: &Context, scene: &Scene) -> Result<SceneGpu> {
        scene.validate()?;
        let level: Vec<u32> = scene.octlevel.iter().map(|&l| l as u32).collect();
        let corners: Vec<u32> = scene.corners.iter().flatten().copied().collect();
        let sh0: Vec<f32> = scene.sh0.iter().flatten().copied().collect();
        let w = scene.shs_per_voxel() * 3;
        let shs = shs_to_device(&scene.shs, scene.num_voxels(), w);
        Ok(SceneGpu {
            octpath: ctx.buffer_from("scene.octpath", &scene.octpath)?,
            level: ctx.buffer_from("scene.level", &level)?,
            corners: ctx.buffer_from("scene.corners", &corners)?,
            geo: ctx.buffer_from("scene.geo", &scene.geo)?,
            sh0: ctx.buffer_from("scene.sh0", &sh0)?,
            shs: ctx.buffer_from("scene.shs", &shs)?,
            voxels: scene.num_voxels() as u32,
            grid_points: scene.num_grid_points() as u32,
            max_level: scene.max_level(),
            sh_degree: scene.sh_degree,
            shs_per_voxel: scene.shs_per_voxel() as u32,
            center: scene.center,
            extent: scene.extent,
            background: scene.background,
            background_frame_mean: scene.background_frame_mean,
        })
    }

    /// Downloads the current parameters (density, SH) into `scene`, whose topology
    /// must be the one this was uploaded from.
    pub fn download_params(&self, ctx: &Context, scene: &mut Scene) -> Result<()> {
        if scene.num_voxels() != self.voxels as usize
            || scene.num_grid_points() != self.grid_points as usize
            || scene.shs_per_voxel() != self.shs_per_voxel as usize
        {
            return Err(Error::Invalid(
                "download_params: the scene's topology differs from the device copy".into(),
            ));
        }
        scene.geo = ctx.download(&self.geo, 0, scene.geo.len())?;
        let sh0: Vec<f32> = ctx.download(&self.sh0, 0, scene.sh0.len() * 3)?;
        scene.sh0 = sh0.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        if !scene.shs.is_empty() {
            let (n, w) = (scene.num_voxels(), scene.shs_per_voxel() * 3);
            scene.shs = download_shs(ctx, &self.shs, n, w)?;
        }
        Ok(())
    }

    /// Device bytes held by the scene.
    pub fn bytes(&self) -> u64 {
        [
            &self.octpath,
            &self.level,
            &self.corners,
            &self.geo,
            &self.sh0,
            &self.shs,
        ]
        .iter()
        .map(|b| b.size())
        .sum()
    }
}
