//! Writes stand-in per-pixel features for `svraster fuse`: one `STEM.npy` (H/2 × W/2 × C
//! float32) per frame of a dataset split, each channel a fixed random smooth function of
//! the photo's colour and the pixel's position (what a network's feature map would be
//! in shape and size, not in meaning). For measuring feature fusion on real data:
//!
//! `cargo run --release --example features -- DATA SPLIT DOWNSCALE CHANNELS OUT`
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().skip(1).collect();
    let [data, split, downscale, channels, out] = &a[..] else {
        return Err("usage: features DATA SPLIT DOWNSCALE CHANNELS OUT".into());
    };
    let (downscale, c): (f64, usize) = (downscale.parse()?, channels.parse()?);
    let ds = svraster::data::load_split(&PathBuf::from(data), split, downscale, [0.0; 3])?;
    let out = PathBuf::from(out);
    std::fs::create_dir_all(&out)?;
    // Fixed coefficients per channel (a simple LCG: reproducible without a seed file).
    let mut s = 0x2545_f491_4f6c_dd1du64;
    let mut next = || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f32 / (1u64 << 53) as f32 * 2.0 - 1.0
    };
    let coef: Vec<[f32; 6]> = (0..c)
        .map(|_| std::array::from_fn(|_| 3.0 * next()))
        .collect();
    for f in &ds.frames {
        let (w, h) = (f.camera.width as usize, f.camera.height as usize);
        let (hw, hh) = ((w / 2).max(1), (h / 2).max(1));
        let mut v = Vec::with_capacity(hw * hh * c);
        for y in 0..hh {
            for x in 0..hw {
                let p = f.rgb[(2 * y).min(h - 1) * w + (2 * x).min(w - 1)];
                let (u, t) = (x as f32 / hw as f32, y as f32 / hh as f32);
                for k in &coef {
                    v.push(
                        (k[0] * p[0] + k[1] * p[1] + k[2] * p[2] + k[3] * u + k[4] * t + k[5])
                            .sin(),
                    );
                }
            }
        }
        let path = out.join(format!("{}.npy", f.name));
        svraster::data::pixels::save_npy(&path, &[hh as u64, hw as u64, c as u64], &v)?;
    }
    println!(
        "wrote {} feature maps of {c} channels to {}",
        ds.frames.len(),
        out.display()
    );
    Ok(())
}
