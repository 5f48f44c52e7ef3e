use super::*;

/// A 64×48 JPEG of a gradient (baseline, as the `image` crate writes it).
fn gradient_jpeg() -> Vec<u8> {
    let (w, h) = (64u32, 48u32);
    let raw: Vec<u8> = (0..w * h)
        .flat_map(|i| {
            let (x, y) = (i % w, i / w);
            [(x * 4) as u8, (y * 5) as u8, ((x + y) * 2) as u8]
        })
        .collect();
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 90)
        .encode(&raw, w, h, image::ExtendedColorType::Rgb8)
        .unwrap();
    out
}

/// A truncated JPEG (an interrupted copy) is an error naming the file; the decoder
/// alone fills the missing rows with grey and succeeds. A complete file loads, also
/// with data after its end-of-image marker (a motion photo's video), and the marker
/// walk sees every truncation point of the file.
#[test]
fn truncated_jpeg_is_an_error_naming_the_file() {
    let dir = temp_dir("jpeg");
    let full = gradient_jpeg();
    let ok = dir.path().join("whole.jpg");
    std::fs::write(&ok, &full).unwrap();
    let (w, h, _) = load_rgba(&ok).unwrap();
    assert_eq!((w, h), (64, 48));

    let cut = dir.path().join("cut.jpg");
    std::fs::write(&cut, &full[..full.len() * 6 / 10]).unwrap();
    let e = load_rgba(&cut).unwrap_err().to_string();
    assert!(
        e.contains("cut.jpg") && e.contains("truncated"),
        "unexpected message: {e}"
    );

    let mut tail = full.clone();
    // Pseudo-random bytes standing in for a video, with a start-of-scan marker in them.
    tail.extend((0..4096u32).map(|i| (i.wrapping_mul(2654435761) >> 13) as u8));
    tail.extend([0xFF, 0xDA, 0x00, 0x10]);
    let trailing = dir.path().join("trailing.jpg");
    std::fs::write(&trailing, &tail).unwrap();
    load_rgba(&trailing).unwrap();

    for len in (0..full.len()).step_by(7) {
        assert!(
            svraster::data::image::jpeg_complete(&full[..len]).is_err(),
            "{len} of {} bytes passed as complete",
            full.len()
        );
    }
    svraster::data::image::jpeg_complete(&full).unwrap();
}

/// The reproduction on a real photo: half of a Mip-NeRF 360 garden frame.
#[test]
fn truncated_capture_photo_is_an_error() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../shared/data/mip360_garden_512/images/frame_00001.jpg");
    if !src.is_file() {
        println!("skipped: {} is absent", src.display());
        return;
    }
    let bytes = std::fs::read(&src).unwrap();
    svraster::data::image::jpeg_complete(&bytes).unwrap();
    let dir = temp_dir("garden-cut");
    let cut = dir.path().join("frame_00001.jpg");
    std::fs::write(&cut, &bytes[..bytes.len() / 2]).unwrap();
    let e = load_rgba(&cut).unwrap_err().to_string();
    assert!(
        e.contains("frame_00001.jpg") && e.contains("truncated"),
        "{e}"
    );
}

/// A PNG whose IHDR announces 2^31 − 1 rows (the file itself 4×4 pixels) is refused,
/// naming the file, before anything is decoded: as a photo or mask ([`load_rgba`]) and as
/// a label image of `fuse`. The decoder sized its buffer from the header and the process
/// aborted.
#[test]
fn png_header_sizes_are_checked_before_decoding() {
    use image::ImageEncoder;
    fn crc32(bytes: &[u8]) -> u32 {
        let mut c = !0u32;
        for &b in bytes {
            c ^= u32::from(b);
            for _ in 0..8 {
                c = if c & 1 == 1 {
                    0xEDB8_8320 ^ (c >> 1)
                } else {
                    c >> 1
                };
            }
        }
        !c
    }
    let dir = temp_dir("png-size");
    let mut png = Vec::new();
    image::codecs::png::PngEncoder::new(&mut png)
        .write_image(&[128u8; 16], 4, 4, image::ExtendedColorType::L8)
        .unwrap();
    let ok = dir.path().join("small.png");
    std::fs::write(&ok, &png).unwrap();
    assert_eq!(load_rgba(&ok).unwrap().1, 4);
    // IHDR: length (4 bytes) at 8, "IHDR" at 12, width at 16, height at 20, CRC at 29.
    assert_eq!(&png[12..16], b"IHDR");
    for (w, h) in [(4u32, (1u32 << 31) - 1), (70_000, 4), (20_000, 20_000)] {
        let mut big = png.clone();
        big[16..20].copy_from_slice(&w.to_be_bytes());
        big[20..24].copy_from_slice(&h.to_be_bytes());
        let crc = crc32(&big[12..29]);
        big[29..33].copy_from_slice(&crc.to_be_bytes());
        let p = dir.path().join("huge.png");
        std::fs::write(&p, &big).unwrap();
        for e in [
            load_rgba(&p).unwrap_err().to_string(),
            svraster::data::pixels::load_labels(&p)
                .unwrap_err()
                .to_string(),
        ] {
            assert!(
                e.contains("huge.png") && e.contains(&format!("{w}×{h}")),
                "{w}×{h}: {e}"
            );
        }
    }
}
