//! Models trained by the reference implementation: SVRaster's checkpoints
//! (NVlabs/svraster `src/sparse_voxel_gears/io.py`, `SVInOut.save`: a `torch.save` of
//! `active_sh_degree`, `scene_center`, `inside_extent`, `scene_extent`, `octpath`,
//! `octlevel`, `_geo_grid_pts`, `_sh0`, `_shs` and `quantized`), read without PyTorch by
//! the `pytorch-reader` crate.
//!
//! SVRaster's model is this engine's: the same octree paths (3 bits per level, level 1
//! in the top bits of 48, `x` the high bit of each triple: `cuda/src/utils.cu`
//! `ijk_2_octpath`), the same levels, one raw density per grid point shared by the
//! voxels' corners, with the grid points in the order of their integer coordinates at
//! level 16 sorted as (x, y, z) rows (`octree_utils.build_grid_pts_link`: `unique(dim=0)`)
//! — the order of [`Scene::grid_keys`] — and the same density activation, SH basis and
//! layout (`_sh0` [N, 3], `_shs` [N, (D+1)² − 1, 3]). So a checkpoint becomes a [`Scene`]
//! by copying: nothing is resampled. Its quantized form (`--save_quantized`: per channel a
//! 256-entry codebook and one byte per value) is dequantized as SVRaster's
//! `dequantization` does.
//!
//! Not in the checkpoint, so chosen by the caller ([`SvrasterImport`]): the background
//! (a training option there: white for NeRF-synthetic, black for DTU, and for Mip-NeRF
//! 360 each frame's own mean colour, `background_frame_mean`) and the supersampling the model
//! was trained with (SVRaster's `ss`, 1.5 by default).

use std::collections::HashMap;
use std::path::Path;

use pytorch_reader::{DType, PickleValue, PytorchReader, Tensor};

use super::{sh_coeffs, Scene, WorldFrame, MAX_SH_DEGREE};
use crate::error::{Error, Result};

/// What an SVRaster checkpoint does not record.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SvrasterImport {
    /// Background colour (display values).
    pub background: [f32; 3],
    /// Each frame's own mean colour as the background instead
    /// ([`Scene::background_frame_mean`]): SVRaster's for models trained neither on
    /// white nor on black (its Mip-NeRF 360 configuration).
    pub background_frame_mean: bool,
    /// Supersampling the model renders at by default (SVRaster's `ss`).
    pub supersample: f32,
}

impl Default for SvrasterImport {
    fn default() -> Self {
        SvrasterImport {
            background: [0.0; 3],
            background_frame_mean: false,
            supersample: 1.5,
        }
    }
}

/// How SVRaster rendered the model of `ckpt`, from the `config.yaml` its training wrote
/// beside `checkpoints/` (`MODEL_DIR/config.yaml`; also looked for in the checkpoint's
/// own folder): `model.white_background` → white, `model.black_background` → black,
/// neither → each frame's own mean colour (its renderer.py), and `model.ss`. `None`
/// when there is no such file; an unreadable one or a value of the wrong type is an
/// error naming it. Returns the options and the file read.
pub fn import_options_from_config(
    ckpt: &Path,
) -> Result<Option<(SvrasterImport, std::path::PathBuf)>> {
    let dir = ckpt.parent().unwrap_or(Path::new("."));
    let candidates = [dir.join("config.yaml"), dir.join("..").join("config.yaml")];
    let Some(path) = candidates.into_iter().find(|p| p.is_file()) else {
        return Ok(None);
    };
    let bad = |what: String| {
        Error::Invalid(format!(
            "{}: {what}; it should be the config.yaml SVRaster wrote for this model (or \
             move it away and pass --background and --ss)",
            path.display()
        ))
    };
    let text = std::fs::read_to_string(&path).map_err(|e| bad(format!("unreadable ({e})")))?;
    let docs =
        yaml_rust2::YamlLoader::load_from_str(&text).map_err(|e| bad(format!("not YAML ({e})")))?;
    let model = docs
        .first()
        .map(|d| &d["model"])
        .filter(|m| !m.is_badvalue())
        .ok_or_else(|| bad("no `model:` section".into()))?;
    let flag = |key: &str| -> Result<bool> {
        let v = &model[key];
        if v.is_badvalue() {
            return Ok(false); // SVRaster's default (src/config.py)
        }
        v.as_bool()
            .ok_or_else(|| bad(format!("model.{key} is not true or false")))
    };
    let (white, black) = (flag("white_background")?, flag("black_background")?);
    let ss = &model["ss"];
    let supersample = if ss.is_badvalue() {
        1.5 // SVRaster's default
    } else {
        ss.as_f64()
            .or_else(|| ss.as_i64().map(|i| i as f64))
            .filter(|v| (1.0..=4.0).contains(v))
            .ok_or_else(|| bad("model.ss is not a number from 1 to 4".into()))? as f32
    };
    let opts = SvrasterImport {
        background: if white { [1.0; 3] } else { [0.0; 3] },
        background_frame_mean: !white && !black,
        supersample,
    };
    Ok(Some((opts, path)))
}

/// Whether `path` looks like a PyTorch checkpoint — a ZIP archive (`torch.save` since
/// 1.6) or a legacy file (a protocol-2 pickle opening with PyTorch's magic number) — as
/// opposed to a safetensors model, whose first 8 bytes are its header's length (neither
/// opening is a plausible length: ≥ 64 MiB of header).
pub fn is_torch_checkpoint(path: &Path) -> bool {
    const LEGACY: [u8; 8] = [0x80, 0x02, 0x8a, 0x0a, 0x6c, 0xfc, 0x9c, 0x46];
    let Ok(mut f) = std::fs::File::open(path) else {
        return false;
    };
    let mut head = [0u8; 8];
    use std::io::Read;
    f.read_exact(&mut head).is_ok() && (head[..4] == *b"PK\x03\x04" || head == LEGACY)
}

struct Reader<'a> {
    path: &'a Path,
    tensors: HashMap<String, Tensor>,
}

impl Reader<'_> {
    fn bad(&self, what: impl std::fmt::Display) -> Error {
        Error::Invalid(format!(
            "{}: {what} (expected an SVRaster checkpoint, `iterNNNNNN_model.pt`, as its \
             SVInOut.save writes)",
            self.path.display()
        ))
    }

    fn tensor(&self, name: &str) -> Result<&Tensor> {
        self.tensors
            .get(name)
            .ok_or_else(|| self.bad(format!("no tensor `{name}`")))
    }

    /// A float tensor's values (f32, f64, f16 or bf16), with its shape checked by `ok`.
    fn floats(&self, name: &str, ok: impl Fn(&[usize]) -> bool, want: &str) -> Result<Vec<f32>> {
        let t = self.tensor(name)?;
        if !ok(t.shape()) {
            return Err(self.bad(format!(
                "`{name}` has shape {:?}, expected {want}",
                t.shape()
            )));
        }
        let b = t
            .read()
            .map_err(|e| self.bad(format!("`{name}` cannot be read: {e}")))?;
        let v: Vec<f32> = match t.dtype() {
            DType::F32 => b
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
                .collect(),
            DType::F64 => b
                .chunks_exact(8)
                .map(|c| f64::from_le_bytes(c.try_into().unwrap()) as f32)
                .collect(),
            DType::F16 => b
                .chunks_exact(2)
                .map(|c| half::f16::from_le_bytes([c[0], c[1]]).to_f32())
                .collect(),
            DType::BF16 => b
                .chunks_exact(2)
                .map(|c| half::bf16::from_le_bytes([c[0], c[1]]).to_f32())
                .collect(),
            d => return Err(self.bad(format!("`{name}` is {d:?}, expected a float tensor"))),
        };
        if let Some(i) = v.iter().position(|x| !x.is_finite()) {
            return Err(self.bad(format!("`{name}` holds {} at element {i}", v[i])));
        }
        Ok(v)
    }

    /// An integer tensor's values (any integer type), shape checked by `ok`.
    fn ints(&self, name: &str, ok: impl Fn(&[usize]) -> bool, want: &str) -> Result<Vec<i64>> {
        let t = self.tensor(name)?;
        if !ok(t.shape()) {
            return Err(self.bad(format!(
                "`{name}` has shape {:?}, expected {want}",
                t.shape()
            )));
        }
        let b = t
            .read()
            .map_err(|e| self.bad(format!("`{name}` cannot be read: {e}")))?;
        Ok(match t.dtype() {
            DType::I64 => b
                .chunks_exact(8)
                .map(|c| i64::from_le_bytes(c.try_into().unwrap()))
                .collect(),
            DType::U64 => b
                .chunks_exact(8)
                .map(|c| u64::from_le_bytes(c.try_into().unwrap()) as i64)
                .collect(),
            DType::I32 => b
                .chunks_exact(4)
                .map(|c| i32::from_le_bytes(c.try_into().unwrap()) as i64)
                .collect(),
            DType::I16 => b
                .chunks_exact(2)
                .map(|c| i16::from_le_bytes([c[0], c[1]]) as i64)
                .collect(),
            DType::I8 => b.iter().map(|&x| x as i8 as i64).collect(),
            DType::U8 => b.iter().map(|&x| x as i64).collect(),
            d => return Err(self.bad(format!("`{name}` is {d:?}, expected an integer tensor"))),
        })
    }

    /// A channel's values: the plain tensor `name`, or SVRaster's quantized form
    /// (`name.index` bytes into the 256-entry `name.codebook`).
    fn channel(
        &self,
        name: &str,
        quantized: bool,
        ok: impl Fn(&[usize]) -> bool,
        want: &str,
    ) -> Result<Vec<f32>> {
        if !quantized {
            return self.floats(name, ok, want);
        }
        let book = self.floats(
            &format!("{name}.codebook"),
            |s| s.iter().product::<usize>() == 256,
            "[256]",
        )?;
        let index = self.ints(&format!("{name}.index"), ok, want)?;
        index
            .iter()
            .map(|&i| {
                book.get(i as usize)
                    .copied()
                    .ok_or_else(|| self.bad(format!("`{name}.index` holds {i}, outside 0..256")))
            })
            .collect()
    }
}

/// Reads an SVRaster checkpoint (plain or quantized) as a [`Scene`]. Errors name the file
/// and the entry that is missing, of the wrong shape or type, or not finite.
pub fn import_svraster(path: &Path, opts: &SvrasterImport) -> Result<Scene> {
    let open_err = |e: pytorch_reader::PytorchError| {
        Error::Invalid(format!(
            "{}: not a readable PyTorch checkpoint ({e}); expected an SVRaster \
             `iterNNNNNN_model.pt`",
            path.display()
        ))
    };
    let reader = PytorchReader::new(path).map_err(open_err)?;
    let values = PytorchReader::read_pickle_data(path, None).map_err(open_err)?;
    let r = Reader {
        path,
        tensors: reader.into_tensors(),
    };
    let PickleValue::Dict(values) = values else {
        return Err(r.bad("the checkpoint is not a dictionary"));
    };
    let active = match values.get("active_sh_degree") {
        Some(PickleValue::Int(d)) if (0..=MAX_SH_DEGREE as i64).contains(d) => *d as u32,
        Some(v) => return Err(r.bad(format!("`active_sh_degree` is {v:?}, expected 0..=3"))),
        None => return Err(r.bad("no `active_sh_degree`")),
    };
    let quantized = match values.get("quantized") {
        Some(PickleValue::Bool(q)) => *q,
        None => false,
        Some(v) => return Err(r.bad(format!("`quantized` is {v:?}, expected a bool"))),
    };

    let center = r.floats("scene_center", |s| s.iter().product::<usize>() == 3, "[3]")?;
    let extent = r.floats("scene_extent", |s| s.iter().product::<usize>() == 1, "[1]")?[0];
    if extent <= 0.0 {
        return Err(r.bad(format!("`scene_extent` is {extent}, expected > 0")));
    }
    let octpath = r.ints(
        "octpath",
        |s| s.len() <= 2 && s.iter().skip(1).all(|&d| d == 1),
        "[N, 1]",
    )?;
    let n = octpath.len();
    let octlevel = r.ints(
        "octlevel",
        |s| s.iter().product::<usize>() == n,
        "[N, 1], N = octpath's",
    )?;
    let mut levels = Vec::with_capacity(n);
    for (i, &l) in octlevel.iter().enumerate() {
        if !(1..=super::MAX_LEVEL as i64).contains(&l) {
            return Err(r.bad(format!(
                "`octlevel`[{i}] is {l}, outside 1..={}",
                super::MAX_LEVEL
            )));
        }
        levels.push(l as u8);
    }
    let paths: Vec<u64> = octpath.iter().map(|&p| p as u64).collect();
    let mut scene = Scene::from_voxels(
        [center[0], center[1], center[2]],
        extent,
        active,
        paths,
        levels,
        0.0,
    )
    .map_err(|e| r.bad(format!("its voxels: {e}")))?;
    let m = scene.grid_keys.len();
    scene.geo = r.channel(
        "_geo_grid_pts",
        quantized,
        |s| s.iter().product::<usize>() == m && s.first() == Some(&m),
        &format!("[{m}, 1]: one per distinct corner of the voxels"),
    )?;
    // sh0: [N, 3]; quantized per channel (`_sh0.c`, [N, 1] each).
    let sh0: Vec<f32> = if quantized {
        let ch: Vec<Vec<f32>> = (0..3)
            .map(|c| {
                r.channel(
                    &format!("_sh0.{c}"),
                    true,
                    |s| s.iter().product::<usize>() == n,
                    "[N, 1]",
                )
            })
            .collect::<Result<_>>()?;
        (0..n)
            .flat_map(|v| [ch[0][v], ch[1][v], ch[2][v]])
            .collect()
    } else {
        r.floats("_sh0", |s| s == [n, 3], &format!("[{n}, 3]"))?
    };
    scene.sh0 = sh0.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    // shs: [N, K, 3] with K ≥ (active + 1)² − 1; quantized per coefficient (`_shs.k`,
    // [N, 1, 3] each). Degrees above the active one are dropped.
    let keep = sh_coeffs(active) - 1;
    let (k_all, shs) = if quantized {
        let k_all = (0..)
            .take_while(|k| r.tensors.contains_key(&format!("_shs.{k}.index")))
            .count();
        let rows: Vec<Vec<f32>> = (0..k_all)
            .map(|k| {
                r.channel(
                    &format!("_shs.{k}"),
                    true,
                    |s| s.iter().product::<usize>() == 3 * n,
                    "[N, 1, 3]",
                )
            })
            .collect::<Result<_>>()?;
        let mut v = vec![0.0; n * k_all * 3];
        for (k, row) in rows.iter().enumerate() {
            for i in 0..n {
                v[(i * k_all + k) * 3..][..3].copy_from_slice(&row[i * 3..][..3]);
            }
        }
        (k_all, v)
    } else {
        let t = r.tensor("_shs")?;
        let k_all = t.shape().get(1).copied().unwrap_or(0);
        let v = r.floats(
            "_shs",
            |s| s.len() == 3 && s[0] == n && s[2] == 3,
            &format!("[{n}, K, 3]"),
        )?;
        (k_all, v)
    };
    if k_all < keep {
        return Err(r.bad(format!(
            "`_shs` holds {k_all} coefficients per voxel, fewer than the {keep} of \
             active_sh_degree {active}"
        )));
    }
    scene.shs = Vec::with_capacity(n * keep * 3);
    for i in 0..n {
        scene
            .shs
            .extend_from_slice(&shs[i * k_all * 3..][..keep * 3]);
    }
    scene.background = opts.background;
    scene.background_frame_mean = opts.background_frame_mean;
    scene.supersample = opts.supersample.max(1.0);
    scene.world = WorldFrame::IDENTITY;
    scene.validate_arrays()?;
    Ok(scene)
}
