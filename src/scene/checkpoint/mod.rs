//! Checkpoint I/O: a [`Scene`] as one [safetensors](https://github.com/huggingface/safetensors)
//! file, readable by any safetensors library or by hand.
//!
//! # Layout
//!
//! ```text
//! [8 bytes]  N: length of the JSON header, unsigned 64-bit little-endian
//! [N bytes]  JSON header (UTF-8), padded with spaces so that the data starts at a
//!            multiple of 8 bytes from the start of the file
//! [rest]     data buffer: the tensors' raw little-endian bytes, back to back, no gaps
//! ```
//!
//! The header is one JSON object. `"__metadata__"` maps strings to strings; every other
//! key is a tensor: `{"dtype": "U64"|"U8"|"F32", "shape": [..], "data_offsets": [begin,
//! end]}`, offsets in bytes relative to the start of the data buffer (`end` exclusive).
//! Tensors are row-major (C order). With `V` voxels, `G` grid points and SH degree `D`:
//!
//! | tensor         | dtype | shape                | content                                    |
//! |----------------|-------|----------------------|--------------------------------------------|
//! | `octpath`      | U64   | `[V]`                | Morton code per voxel (see [`crate::scene`]) |
//! | `octlevel`     | U8    | `[V]`                | octree level per voxel, 1..=16             |
//! | `geo_grid_pts` | F32   | `[G]`                | raw density per grid point                 |
//! | `sh0`          | F32   | `[V, 3]`             | degree-0 SH per voxel, RGB                 |
//! | `shs`          | F32   | `[V, (D+1)²−1, 3]`   | higher-degree SH (`[V, 0, 3]`, empty, for D = 0) |
//!
//! `octpath` holds 3 bits per level (`x<<2 | y<<1 | z`), level 1 in bits 45..48, all bits
//! below the voxel's own level zero. A voxel at level `l` with index `(i, j, k)` covers
//! `[i, i+1] × [j, j+1] × [k, k+1] · 2^(16−l)` in integer coordinates of the finest grid
//! (0..=65536 per axis). The grid points are the *unique* corners of all voxels, and
//! `geo_grid_pts` lists their densities ordered by ascending key `x<<34 | y<<17 | z`
//! (integer finest-grid coordinates); a voxel's 8 corner densities are found by
//! computing its corner keys and binary-searching them (e.g. `np.searchsorted`).
//!
//! Metadata (all values are strings, as safetensors requires):
//!
//! | key            | value                                                       |
//! |----------------|-------------------------------------------------------------|
//! | `format`       | `svraster-vk/1`                                             |
//! | `scene_center` | JSON array `[x,y,z]`: world centre of the root cube         |
//! | `scene_extent` | number: full edge length of the root cube in world units   |
//! | `sh_degree`    | `0`, `1`, `2` or `3`                                        |
//! | `background`   | JSON array `[r,g,b]`: background colour                     |
//! | `background_mode` | `frame_mean` (optional: `colour`): composite each frame's own mean colour instead (`Scene::background_frame_mean`) |
//! | `supersample`  | number in [1, 8]: default render supersampling (optional: 1) |
//! | `world_center` | JSON array `[x,y,z]` (optional: `[0,0,0]`); with `world_scale` (optional: 1) the capture's frame: model = (world − world_center) / world_scale; cameras of the capture are mapped so before rendering, depths scale back by `world_scale` |
//! | `world_scale`  | number > 0 (optional: 1), written as f64 text               |
//!
//! | `quantized`    | `kmeans8` (optional): an 8-bit file, see below              |
//!
//! An 8-bit quantized checkpoint ([`save_quantized`], metadata `quantized` = `kmeans8`)
//! replaces `geo_grid_pts`, `sh0` and `shs` by U8 codes of the same shapes
//! (`geo_grid_pts_q`, `sh0_q`, `shs_q`) and per-channel codebooks F32 `[channels, 256]`
//! (`geo_grid_pts_codebook` with 1 channel, `sh0_codebook` with 3, `shs_codebook` with
//! `3·((D+1)²−1)` in `shs`'s (coefficient, rgb) order); value = `codebook[channel][code]`.
//! [`load`] returns the dequantized scene.
//!
//! Numbers are written in the shortest form that reads back as the identical `f32`.
//! Other metadata keys are ignored on load. Loading is strict: unknown tensors, gaps or
//! overlaps in the data buffer, non-finite values, out-of-range levels, stray path bits,
//! overlapping voxels or a grid-point count that does not match the voxels are errors.
//!
//! # Reading it from Python with only `json` and `numpy`
//!
//! ```python
//! import json, numpy as np
//! def load_svraster(path):
//!     raw = open(path, "rb").read()
//!     n = int.from_bytes(raw[:8], "little")
//!     header = json.loads(raw[8:8 + n])
//!     meta = header.pop("__metadata__")  # strings; json.loads(meta["scene_center"]) etc.
//!     dt = {"U64": "<u8", "U8": "u1", "F32": "<f4"}
//!     t = {k: np.frombuffer(raw[8 + n + v["data_offsets"][0]:8 + n + v["data_offsets"][1]],
//!                           dtype=dt[v["dtype"]]).reshape(v["shape"]) for k, v in header.items()}
//!     return meta, t  # t["octpath"], t["octlevel"], t["geo_grid_pts"], t["sh0"], t["shs"]
//! ```

use std::fs;
use std::io::{self, Write};
use std::path::Path;

mod read;

use read::parse;
use serde_json::Value;

use super::Scene;
use crate::error::{Error, Result};

/// Value of the `format` metadata key.
pub const FORMAT: &str = "svraster-vk/1";

/// Value of the optional `background_mode` metadata key for a frame-mean background.
const BACKGROUND_FRAME_MEAN: &str = "frame_mean";
/// Its default: the `background` colour.
const BACKGROUND_COLOUR: &str = "colour";

/// Largest accepted JSON header (the same bound the safetensors library uses).
pub const MAX_HEADER_BYTES: u64 = 100_000_000;

/// Tensor names, dtypes and element sizes, in the order they are laid out in the data
/// buffer (8-byte elements first, so every tensor starts aligned to its element size).
const TENSORS: [(&str, &str, usize); 5] = [
    ("octpath", "U64", 8),
    ("geo_grid_pts", "F32", 4),
    ("sh0", "F32", 4),
    ("shs", "F32", 4),
    ("octlevel", "U8", 1),
];

/// Value of the `quantized` metadata key of an 8-bit quantized checkpoint.
pub const QUANTIZED: &str = "kmeans8";

/// The tensors of a quantized checkpoint (metadata `quantized` = [`QUANTIZED`]): per
/// channel a codebook of 256 values (`*_codebook`, F32 `[channels, 256]`) and per value
/// the U8 index of its entry (`*_q`, the shape of the full-precision tensor).
const QTENSORS: [(&str, &str, usize); 8] = [
    ("octpath", "U64", 8),
    ("geo_grid_pts_codebook", "F32", 4),
    ("sh0_codebook", "F32", 4),
    ("shs_codebook", "F32", 4),
    ("geo_grid_pts_q", "U8", 1),
    ("sh0_q", "U8", 1),
    ("shs_q", "U8", 1),
    ("octlevel", "U8", 1),
];

/// Writes `scene` to `path` atomically: the checkpoint goes to a temporary file in the
/// same directory, is flushed to disk, then renamed over `path`. On any error the
/// temporary file is removed and an existing file at `path` is left untouched. The scene
/// is validated first; an invalid scene (e.g. containing NaN) is refused.
pub fn save(scene: &Scene, path: &Path) -> Result<()> {
    let header = encode_header(scene)?;
    crate::fsio::write_atomic_with(path, |w| {
        w.write_all(&header)?;
        write_data(scene, w)
    })
    .map_err(|e| match e {
        Error::Io { path, error } => Error::Io {
            path,
            error: io::Error::new(error.kind(), format!("cannot save the checkpoint: {error}")),
        },
        e => e,
    })
}

/// Writes `scene` 8-bit quantized (see [`crate::scene::quantize`]; ~70 % smaller) to
/// `path`, atomically like [`save`]. [`load`] reads it back as a full-precision scene
/// whose values are the codebook entries.
pub fn save_quantized(scene: &Scene, path: &Path) -> Result<()> {
    let bytes = to_bytes_quantized(scene)?;
    crate::fsio::write_atomic(path, &bytes)
}

/// The quantized checkpoint file's bytes for `scene` (validated first).
pub fn to_bytes_quantized(scene: &Scene) -> Result<Vec<u8>> {
    use super::quantize::{quantize_channels, CODES};
    let k = scene.shs_per_voxel();
    let (geo_b, geo_q) = quantize_channels(&scene.geo, 1);
    let (sh0_b, sh0_q) = quantize_channels(bytemuck::cast_slice(&scene.sh0), 3);
    let (shs_b, shs_q) = quantize_channels(&scene.shs, 3 * k);
    let n = scene.num_voxels();
    let m = scene.num_grid_points();
    let shapes: [(Vec<usize>, usize); 8] = [
        (vec![n], n * 8),
        (vec![1, CODES], CODES * 4),
        (vec![3, CODES], 3 * CODES * 4),
        (vec![3 * k, CODES], 3 * k * CODES * 4),
        (vec![m], m),
        (vec![n, 3], 3 * n),
        (vec![n, k, 3], 3 * k * n),
        (vec![n], n),
    ];
    let mut out = encode_header_for(scene, &QTENSORS, &shapes, true)?;
    for v in &scene.octpath {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for book in geo_b.iter().chain(&sh0_b).chain(&shs_b) {
        for v in book {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    out.extend_from_slice(&geo_q);
    out.extend_from_slice(&sh0_q);
    out.extend_from_slice(&shs_q);
    out.extend_from_slice(&scene.octlevel);
    Ok(out)
}

/// Reads and fully validates a checkpoint written by [`save`] (or any tool following the
/// format in the module documentation).
pub fn load(path: &Path) -> Result<Scene> {
    let bytes = fs::read(path).map_err(|error| Error::Io {
        path: path.display().to_string(),
        error,
    })?;
    parse(&bytes, &path.display().to_string())
}

/// The checkpoint file's bytes for `scene` (validated first).
pub fn to_bytes(scene: &Scene) -> Result<Vec<u8>> {
    let header = encode_header(scene)?;
    let mut out = Vec::with_capacity(header.len() + data_len(scene));
    out.extend_from_slice(&header);
    write_data(scene, &mut out).map_err(|error| Error::Io {
        path: "<memory>".into(),
        error,
    })?;
    Ok(out)
}

/// Parses and fully validates checkpoint bytes (see [`load`]).
pub fn from_bytes(bytes: &[u8]) -> Result<Scene> {
    parse(bytes, "<memory>")
}

// ---------------------------------------------------------------------------------------
// Writing

/// Shapes and byte sizes of the tensors, in [`TENSORS`] order.
fn shapes(scene: &Scene) -> [(Vec<usize>, usize); 5] {
    let n = scene.num_voxels();
    let k = scene.shs_per_voxel();
    let m = scene.num_grid_points();
    [
        (vec![n], n * 8),
        (vec![m], m * 4),
        (vec![n, 3], n * 12),
        (vec![n, k, 3], n * k * 12),
        (vec![n], n),
    ]
}

fn data_len(scene: &Scene) -> usize {
    shapes(scene).iter().map(|s| s.1).sum()
}

/// Validates the scene and returns the length prefix plus the padded JSON header.
fn encode_header(scene: &Scene) -> Result<Vec<u8>> {
    encode_header_for(scene, &TENSORS, &shapes(scene), false)
}

/// [`encode_header`] for a tensor table and its shapes and byte sizes.
fn encode_header_for(
    scene: &Scene,
    table: &[(&str, &str, usize)],
    shapes: &[(Vec<usize>, usize)],
    quantized: bool,
) -> Result<Vec<u8>> {
    scene.validate().map_err(|e| match e {
        Error::Invalid(m) => Error::Invalid(format!("refusing to save an invalid scene: {m}")),
        e => e,
    })?;
    let mut header = serde_json::Map::new();
    let mut meta = serde_json::Map::new();
    let vec3 = |v: [f32; 3]| format!("[{},{},{}]", num(v[0]), num(v[1]), num(v[2]));
    meta.insert("format".into(), FORMAT.into());
    meta.insert("scene_center".into(), vec3(scene.center).into());
    meta.insert("scene_extent".into(), num(scene.extent).into());
    meta.insert("sh_degree".into(), scene.sh_degree.to_string().into());
    meta.insert("background".into(), vec3(scene.background).into());
    meta.insert("supersample".into(), num(scene.supersample).into());
    if scene.background_frame_mean {
        meta.insert("background_mode".into(), BACKGROUND_FRAME_MEAN.into());
    }
    if quantized {
        meta.insert("quantized".into(), QUANTIZED.into());
    }
    if !scene.world.is_identity() {
        let c = scene.world.center;
        meta.insert(
            "world_center".into(),
            format!("[{:?},{:?},{:?}]", c[0], c[1], c[2]).into(),
        );
        meta.insert(
            "world_scale".into(),
            format!("{:?}", scene.world.scale).into(),
        );
    }
    header.insert("__metadata__".into(), Value::Object(meta));
    let mut offset = 0usize;
    for ((name, dtype, _), (shape, bytes)) in table.iter().zip(shapes) {
        header.insert(
            (*name).into(),
            serde_json::json!({
                "dtype": dtype,
                "shape": shape,
                "data_offsets": [offset, offset + *bytes],
            }),
        );
        offset += *bytes;
    }
    let mut json = serde_json::to_vec(&Value::Object(header))
        .map_err(|e| Error::Invalid(format!("cannot encode the checkpoint header: {e}")))?;
    while (8 + json.len()) % 8 != 0 {
        json.push(b' ');
    }
    let mut out = Vec::with_capacity(8 + json.len());
    out.extend_from_slice(&(json.len() as u64).to_le_bytes());
    out.extend_from_slice(&json);
    Ok(out)
}

/// Shortest decimal text that parses back to the identical `f32` (a valid JSON number):
/// plain notation for ordinary magnitudes, exponent notation for tiny or huge ones.
fn num(v: f32) -> String {
    let a = v.abs();
    if a != 0.0 && !(1e-5..1e16).contains(&a) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

/// Writes the data buffer (tensors in [`TENSORS`] order, little-endian).
fn write_data<W: Write + ?Sized>(scene: &Scene, w: &mut W) -> io::Result<()> {
    if cfg!(target_endian = "little") {
        w.write_all(bytemuck::cast_slice(&scene.octpath))?;
        w.write_all(bytemuck::cast_slice(&scene.geo))?;
        w.write_all(bytemuck::cast_slice(&scene.sh0))?;
        w.write_all(bytemuck::cast_slice(&scene.shs))?;
    } else {
        for v in &scene.octpath {
            w.write_all(&v.to_le_bytes())?;
        }
        let sh0: &[f32] = bytemuck::cast_slice(&scene.sh0);
        for v in scene.geo.iter().chain(sh0).chain(&scene.shs) {
            w.write_all(&v.to_le_bytes())?;
        }
    }
    w.write_all(&scene.octlevel)
}
