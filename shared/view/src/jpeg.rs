//! Camera frames as small JPEGs for the view and recordings.

use image::ColorType;
use image::codecs::jpeg::JpegEncoder;
use isochron_wire::PixelFormat;

/// The whole factor a `w × h` frame is divided by so that its longer side is at
/// most `max_px` (1: as it is).
pub fn scale_factor(w: u32, h: u32, max_px: u32) -> u32 {
    w.max(h).div_ceil(max_px.max(1)).max(1)
}

/// Encodes a frame (`gray8` or `bgr8`, rows `stride` bytes apart) scaled down by
/// [`scale_factor`] (each output pixel the mean of its source pixels) as JPEG;
/// `None` if the pixels do not cover the frame.
pub fn encode(
    pixels: &[u8],
    w: u32,
    h: u32,
    stride: u32,
    format: PixelFormat,
    max_px: u32,
    quality: u8,
) -> Option<Vec<u8>> {
    let channels = match format {
        PixelFormat::Gray8 => 1usize,
        PixelFormat::Bgr8 => 3,
    };
    let (w, h, stride) = (w as usize, h as usize, stride as usize);
    if w == 0 || h == 0 || stride < w * channels || pixels.len() < stride * (h - 1) + w * channels {
        return None;
    }
    let f = scale_factor(w as u32, h as u32, max_px) as usize;
    let (ow, oh) = (w / f, h / f);
    if ow == 0 || oh == 0 {
        return None;
    }
    let mut out = vec![0u8; ow * oh * channels];
    let n = (f * f) as u32;
    for oy in 0..oh {
        for ox in 0..ow {
            for c in 0..channels {
                let mut sum = 0u32;
                for dy in 0..f {
                    let row = &pixels[(oy * f + dy) * stride..];
                    for dx in 0..f {
                        sum += row[(ox * f + dx) * channels + c] as u32;
                    }
                }
                // BGR → RGB on the way.
                let to = if channels == 3 { 2 - c } else { c };
                out[(oy * ow + ox) * channels + to] = (sum / n) as u8;
            }
        }
    }
    let color = if channels == 3 {
        ColorType::Rgb8
    } else {
        ColorType::L8
    };
    let mut jpeg = Vec::new();
    JpegEncoder::new_with_quality(&mut jpeg, quality.clamp(1, 100))
        .encode(&out, ow as u32, oh as u32, color)
        .ok()?;
    Some(jpeg)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frames_are_scaled_to_fit_and_encoded() {
        assert_eq!(scale_factor(768, 576, 640), 2);
        assert_eq!(scale_factor(320, 240, 640), 1);
        let (w, h) = (768u32, 576u32);
        let stride = w * 3 + 16;
        let pixels: Vec<u8> = (0..stride * h).map(|i| (i % 251) as u8).collect();
        let jpeg = encode(&pixels, w, h, stride, PixelFormat::Bgr8, 640, 75).unwrap();
        assert_eq!(&jpeg[..2], &[0xFF, 0xD8], "a JPEG");
        // The SOF0 marker gives the encoded size: 384 × 288.
        let sof = jpeg.windows(2).position(|m| m == [0xFF, 0xC0]).unwrap();
        let be = |i: usize| u16::from_be_bytes([jpeg[i], jpeg[i + 1]]);
        assert_eq!((be(sof + 7), be(sof + 5)), (384, 288));
        assert!(encode(&pixels[..100], w, h, stride, PixelFormat::Bgr8, 640, 75).is_none());
        let gray = vec![128u8; 320 * 240];
        assert!(encode(&gray, 320, 240, 320, PixelFormat::Gray8, 640, 75).is_some());
    }
}
