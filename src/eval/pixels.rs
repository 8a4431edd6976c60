//! Pixel scores of a generated render against the teacher's, on foreground pixels only:
//! renders shown on a grey background, PSNR and SSIM over the union of both images'
//! touched pixels, and the silhouettes' IoU, halo and holes. Scores are taken on the
//! sRGB-encoded shown values, as the trainer's `splats.psnr` / `splats.ssim` are.

use std::sync::OnceLock;

/// A render as premultiplied linear RGBA floats, row-major.
#[derive(Clone)]
pub struct LinearImage {
    pub width: usize,
    pub height: usize,
    pub rgba: Vec<[f32; 4]>,
}

/// The backgrounds every score is taken on: (name, sRGB grey level).
pub const BACKGROUNDS: [(&str, f32); 3] = [("white", 1.0), ("grey", 0.5), ("black", 0.0)];
/// Foreground: alpha at or above this (for IoU, halo, holes).
pub const SOLID: f32 = 0.5;
/// Pixels a score is taken over: alpha above this in either image.
pub const TOUCHED: f32 = 1.0 / 255.0;

const WINDOW: usize = 11;
const HALF: usize = WINDOW / 2;
const C1: f64 = 0.01 * 0.01;
const C2: f64 = 0.03 * 0.03;

fn to_linear(c: f32) -> f32 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

fn to_srgb(x: f32) -> f32 {
    let x = x.clamp(0.0, 1.0);
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

fn decode_table() -> &'static [f32; 256] {
    static TABLE: OnceLock<[f32; 256]> = OnceLock::new();
    TABLE.get_or_init(|| std::array::from_fn(|i| to_linear(i as f32 / 255.0)))
}

impl LinearImage {
    /// A render read back from an sRGB target: RGB is sRGB-encoded premultiplied colour,
    /// alpha is linear coverage.
    pub fn from_srgb8(image: &image::RgbaImage) -> Self {
        let table = decode_table();
        let decode = |p: &image::Rgba<u8>| {
            let [r, g, b] = [0, 1, 2].map(|c| table[p.0[c] as usize]);
            [r, g, b, p.0[3] as f32 / 255.0]
        };
        let (width, height) = (image.width() as usize, image.height() as usize);
        Self {
            width,
            height,
            rgba: image.pixels().map(decode).collect(),
        }
    }

    /// The sub-image x0..x0+w, y0..y0+h, clamped to the image (may come out smaller;
    /// never panics, may be empty).
    pub fn crop(&self, x0: i64, y0: i64, w: usize, h: usize) -> Self {
        let span = |start: i64, len: usize, n: usize| {
            let end = start.saturating_add(i64::try_from(len).unwrap_or(i64::MAX));
            let clamp = |v: i64| v.clamp(0, n as i64) as usize;
            clamp(start)..clamp(end)
        };
        let (xs, ys) = (span(x0, w, self.width), span(y0, h, self.height));
        let row = |y: usize| &self.rgba[y * self.width + xs.start..y * self.width + xs.end];
        let rgba: Vec<_> = ys.clone().flat_map(|y| row(y).iter().copied()).collect();
        Self {
            width: xs.len(),
            height: ys.len(),
            rgba,
        }
    }

    /// The image `factor` times smaller, each pixel the mean of a `factor`² block
    /// (premultiplied linear RGBA: a box filter over that many samples per pixel).
    pub fn downsample(&self, factor: usize) -> Self {
        if factor <= 1 {
            return Self {
                width: self.width,
                height: self.height,
                rgba: self.rgba.clone(),
            };
        }
        let (width, height) = (self.width / factor, self.height / factor);
        let weight = 1.0 / (factor * factor) as f32;
        let mut rgba = vec![[0.0f32; 4]; width * height];
        for (y, row) in rgba.chunks_exact_mut(width).enumerate() {
            for (x, out) in row.iter_mut().enumerate() {
                for sy in 0..factor {
                    let start = (y * factor + sy) * self.width + x * factor;
                    for p in &self.rgba[start..start + factor] {
                        for c in 0..4 {
                            out[c] += p[c] * weight;
                        }
                    }
                }
            }
        }
        Self {
            width,
            height,
            rgba,
        }
    }

    /// sRGB-encoded RGB values of this image shown on a grey background given as an sRGB
    /// level (0 black, 0.5 mid-grey, 1 white): premultiplied colour over the background
    /// in linear light, then encoded.
    pub fn shown(&self, background: f32) -> Vec<[f32; 3]> {
        let bg = to_linear(background);
        let show = |&[r, g, b, a]: &[f32; 4]| [r, g, b].map(|c| to_srgb(c + (1.0 - a) * bg));
        self.rgba.iter().map(show).collect()
    }
}

/// How much two frames from the same cameras differ: per view, the mean absolute
/// difference of the shown (sRGB, mid-grey background) values over the pixels touched in
/// either, then the mean over the views (0 for no touched pixel). Flicker compares this
/// frame-to-frame change of the generated frames with the teacher's.
pub fn mean_change(a: &[LinearImage], b: &[LinearImage]) -> f64 {
    let per_view: Vec<f64> = a
        .iter()
        .zip(b)
        .map(|(a, b)| {
            same_size(a, b);
            let (sa, sb) = (a.shown(0.5), b.shown(0.5));
            let (mut total, mut n) = (0.0f64, 0usize);
            for i in 0..a.rgba.len() {
                if a.rgba[i][3] > TOUCHED || b.rgba[i][3] > TOUCHED {
                    total += (0..3)
                        .map(|c| (sa[i][c] - sb[i][c]).abs() as f64)
                        .sum::<f64>()
                        / 3.0;
                    n += 1;
                }
            }
            if n == 0 { 0.0 } else { total / n as f64 }
        })
        .collect();
    per_view.iter().sum::<f64>() / per_view.len().max(1) as f64
}

/// Both images must describe the same frame; anything else is a caller's bug.
fn same_size(got: &LinearImage, want: &LinearImage) {
    let size = |i: &LinearImage| (i.width, i.height, i.rgba.len());
    assert_eq!(size(got), size(want), "renders differ in size");
    assert_eq!(
        got.rgba.len(),
        got.width * got.height,
        "render has the wrong length"
    );
}

#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct Silhouette {
    pub iou: f64,
    pub halo: f64,
    pub holes: f64,
}

/// IoU of the two SOLID masks; halo = |generated-only| / |generated|; holes =
/// |teacher-only| / |teacher| (0 where the denominator is 0; IoU 1 when both are empty).
pub fn silhouette(got: &LinearImage, want: &LinearImage) -> Silhouette {
    same_size(got, want);
    let (mut both, mut only_got, mut only_want) = (0usize, 0usize, 0usize);
    for (g, w) in got.rgba.iter().zip(&want.rgba) {
        match (g[3] >= SOLID, w[3] >= SOLID) {
            (true, true) => both += 1,
            (true, false) => only_got += 1,
            (false, true) => only_want += 1,
            (false, false) => {}
        }
    }
    let ratio = |a: usize, b: usize| if b == 0 { 0.0 } else { a as f64 / b as f64 };
    let union = both + only_got + only_want;
    Silhouette {
        iou: if union == 0 { 1.0 } else { ratio(both, union) },
        halo: ratio(only_got, both + only_got),
        holes: ratio(only_want, both + only_want),
    }
}

/// PSNR (dB) over the union of TOUCHED pixels of both (3 channels), shown on
/// `background`; f64::INFINITY when equal or when the union is empty.
pub fn psnr(got: &LinearImage, want: &LinearImage, background: f32) -> f64 {
    same_size(got, want);
    let bg = to_linear(background);
    let (mut sum, mut count) = (0.0f64, 0usize);
    for (g, w) in got.rgba.iter().zip(&want.rgba) {
        if g[3] > TOUCHED || w[3] > TOUCHED {
            count += 3;
            for c in 0..3 {
                let a = to_srgb(g[c] + (1.0 - g[3]) * bg);
                let b = to_srgb(w[c] + (1.0 - w[3]) * bg);
                sum += (a as f64 - b as f64).powi(2);
            }
        }
    }
    if count == 0 || sum == 0.0 {
        return f64::INFINITY;
    }
    -10.0 * (sum / count as f64).log10()
}

/// The trainer's `_window` taps: a normalised Gaussian, σ 1.5 (separable, so 1-D).
fn gaussian() -> [f64; WINDOW] {
    let mut g: [f64; WINDOW] = std::array::from_fn(|i| {
        let d = i as f64 - HALF as f64;
        (-d * d / (2.0 * 1.5 * 1.5)).exp()
    });
    let sum: f64 = g.iter().sum();
    g.iter_mut().for_each(|v| *v /= sum);
    g
}

/// Mean SSIM over the union mask: Wang et al. 2004 with an 11×11 Gaussian window, σ = 1.5,
/// C1 = 0.01², C2 = 0.03², data range 1, per RGB channel, valid windows only (a window is
/// taken where it fits entirely in the image), as the trainer's `splats.ssim`; a window's
/// value (mean of the 3 channels) counts when its centre pixel is in the union of TOUCHED
/// pixels. 1.0 when the union is empty; the mean over all valid windows when no valid
/// centre is in the union; the whole image as one uniform window when it is smaller than
/// a window.
pub fn ssim(got: &LinearImage, want: &LinearImage, background: f32) -> f64 {
    same_size(got, want);
    let (w, h) = (got.width, got.height);
    let (gs, ws) = (got.rgba.iter(), want.rgba.iter());
    let union: Vec<bool> = gs
        .zip(ws)
        .map(|(g, w)| g[3] > TOUCHED || w[3] > TOUCHED)
        .collect();
    // Bounding box of the union, exclusive ends.
    let (mut x0, mut x1, mut y0, mut y1) = (w, 0, h, 0);
    for (i, _) in union.iter().enumerate().filter(|(_, u)| **u) {
        let (x, y) = (i % w, i / w);
        (x0, x1, y0, y1) = (x0.min(x), x1.max(x + 1), y0.min(y), y1.max(y + 1));
    }
    if x0 >= x1 {
        return 1.0;
    }
    if w < WINDOW || h < WINDOW {
        return whole_image(&got.shown(background), &want.shown(background));
    }
    // Valid window centres are HALF..n-HALF; only those in the box can be in the union,
    // and their windows lie in the box grown by HALF.
    let (cx, cy) = (
        x0.max(HALF)..x1.min(w - HALF),
        y0.max(HALF)..y1.min(h - HALF),
    );
    let centred = cy.clone().any(|y| cx.clone().any(|x| union[y * w + x]));
    let (cx, cy) = if centred {
        (cx, cy)
    } else {
        (HALF..w - HALF, HALF..h - HALF)
    };
    let (cw, ch) = (cx.len(), cy.len());
    let (bx, by) = ((cx.start - HALF) as i64, (cy.start - HALF) as i64);
    let shown = |i: &LinearImage| {
        i.crop(bx, by, cw + 2 * HALF, ch + 2 * HALF)
            .shown(background)
    };
    let map = ssim_map(&shown(got), &shown(want), cw, ch);
    let (mut total, mut count) = (0.0f64, 0usize);
    for (i, value) in map.iter().enumerate() {
        if !centred || union[(cy.start + i / cw) * w + cx.start + i % cw] {
            total += value;
            count += 1;
        }
    }
    total / count.max(1) as f64
}

/// The SSIM map (mean of the channels) of the valid windows of two images of
/// (cw + 10) × (ch + 10) pixels. Separable: each input row's five moment maps are filtered
/// along x into a ring of the last 11 rows, which is filtered along y for one output row,
/// so the working set stays in cache.
fn ssim_map(a: &[[f32; 3]], b: &[[f32; 3]], cw: usize, ch: usize) -> Vec<f64> {
    let g = gaussian();
    let bw = cw + 2 * HALF;
    let mut map = vec![0.0f64; cw * ch];
    let mut products = [(); 5].map(|_| vec![0.0f64; bw]);
    let mut ring: Vec<[Vec<f64>; 5]> = (0..WINDOW)
        .map(|_| [(); 5].map(|_| vec![0.0f64; cw]))
        .collect();
    let mut moments = [(); 5].map(|_| vec![0.0f64; cw]);
    for c in 0..3 {
        for y in 0..ch + 2 * HALF {
            let rows = a[y * bw..(y + 1) * bw].iter().zip(&b[y * bw..(y + 1) * bw]);
            for (x, (p, q)) in rows.enumerate() {
                let (p, q) = (p[c] as f64, q[c] as f64);
                for (plane, v) in products.iter_mut().zip([p, q, p * p, q * q, p * q]) {
                    plane[x] = v;
                }
            }
            for (dst, src) in ring[y % WINDOW].iter_mut().zip(&products) {
                dst.fill(0.0);
                for (k, &gk) in g.iter().enumerate() {
                    dst.iter_mut()
                        .zip(&src[k..k + cw])
                        .for_each(|(d, s)| *d += gk * s);
                }
            }
            let Some(top) = (y + 1).checked_sub(WINDOW) else {
                continue;
            };
            for (m, moment) in moments.iter_mut().enumerate() {
                moment.fill(0.0);
                for (k, &gk) in g.iter().enumerate() {
                    let row = &ring[(top + k) % WINDOW][m];
                    moment.iter_mut().zip(row).for_each(|(d, s)| *d += gk * s);
                }
            }
            let [mx, my, xx, yy, xy] = &moments;
            let out = map[top * cw..(top + 1) * cw].iter_mut();
            for (x, o) in out.enumerate() {
                *o += window_ssim([mx[x], my[x], xx[x], yy[x], xy[x]]) / 3.0;
            }
        }
    }
    map
}

/// SSIM of one window from its weighted moments [μx, μy, E[x²], E[y²], E[xy]].
fn window_ssim([mx, my, xx, yy, xy]: [f64; 5]) -> f64 {
    let (vx, vy, cxy) = (xx - mx * mx, yy - my * my, xy - mx * my);
    ((2.0 * mx * my + C1) * (2.0 * cxy + C2)) / ((mx * mx + my * my + C1) * (vx + vy + C2))
}

/// SSIM of whole images taken as one window with uniform weights (mean of the channels).
fn whole_image(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    let n = a.len().max(1) as f64;
    let channel = |c: usize| {
        let mut m = [0.0f64; 5];
        for (p, q) in a.iter().zip(b) {
            let (p, q) = (p[c] as f64, q[c] as f64);
            m.iter_mut()
                .zip([p, q, p * p, q * q, p * q])
                .for_each(|(m, v)| *m += v / n);
        }
        window_ssim(m)
    };
    (channel(0) + channel(1) + channel(2)) / 3.0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn image(size: u32, pixel: impl Fn(u32, u32) -> [u8; 4]) -> LinearImage {
        LinearImage::from_srgb8(&image::RgbaImage::from_fn(size, size, |x, y| {
            image::Rgba(pixel(x, y))
        }))
    }

    fn linear(width: usize, rgba: Vec<[f32; 4]>) -> LinearImage {
        LinearImage {
            width,
            height: rgba.len() / width.max(1),
            rgba,
        }
    }

    fn near(got: f64, want: f64, tolerance: f64) {
        assert!((got - want).abs() < tolerance, "{got} is not {want}");
    }

    /// The SSIM test pair (mirrored in the Python snippet below): integer patterns,
    /// opaque where `inside` holds, transparent black elsewhere.
    fn pattern(second: bool, inside: impl Fn(u32, u32) -> bool) -> LinearImage {
        image(32, |x, y| {
            let a = [
                (7 * x + 3 * y) % 200 + 30,
                (x * y) % 97 + 80,
                (x * x + 2 * y) % 150 + 50,
            ];
            let noisy = [0, 1, 2].map(|c| a[c as usize] + (5 * x + 11 * y + 3 * c) % 31 - 15);
            let [r, g, b] = (if second { noisy } else { a }).map(|v| v as u8);
            [r, g, b, 255].map(|v| v * inside(x, y) as u8)
        })
    }

    fn disc(r2: i64) -> impl Fn(u32, u32) -> bool {
        move |x, y| (2 * x as i64 - 31).pow(2) + (2 * y as i64 - 31).pow(2) <= r2
    }

    /// A linear value whose shown sRGB value is exactly `v` in f32.
    fn showing(v: f32) -> f32 {
        let bits = to_linear(v).to_bits();
        let mut candidates = (bits.saturating_sub(64)..bits + 64).map(f32::from_bits);
        candidates.find(|&l| to_srgb(l) == v).unwrap_or(f32::NAN)
    }

    #[test]
    fn identical_images_score_perfectly() {
        let a = pattern(true, disc(300));
        for (_, bg) in BACKGROUNDS {
            assert_eq!(psnr(&a, &a, bg), f64::INFINITY);
            near(ssim(&a, &a, bg), 1.0, 1e-12);
        }
        let s = silhouette(&a, &a);
        assert_eq!((s.iou, s.halo, s.holes), (1.0, 0.0, 0.0));
    }

    #[test]
    fn psnr_of_a_tenth_everywhere_is_20_db_and_ignores_untouched_pixels() {
        // Opaque 8×8 squares shown exactly 0.1f32 apart in every channel (0.0 and 0.1f32
        // are exact shown values); outside, the teacher's alpha is TOUCHED, not above it.
        let square = |colour: [f32; 3], outside: [f32; 4]| {
            let [r, g, b] = colour.map(showing);
            let inside = |i: usize| (4..12).contains(&(i % 16)) && (4..12).contains(&(i / 16));
            let rgba = (0..256).map(|i| if inside(i) { [r, g, b, 1.0] } else { outside });
            linear(16, rgba.collect())
        };
        let got = square([0.1, 0.0, 0.1], [0.0; 4]);
        let faint = [0.2, 0.5, 0.0, 1.0].map(|v| v * TOUCHED);
        let want = square([0.0, 0.1, 0.0], faint);
        for (_, bg) in BACKGROUNDS {
            near(psnr(&got, &want, bg), 20.0, 1e-6);
        }
    }

    #[test]
    fn offset_squares_give_exact_silhouette_fractions() {
        // Generated 10×10 at (0, 0); teacher 10×20 at (5, 0): 50 shared, 50 generated
        // only, 150 teacher only; the generated image's alpha 127 elsewhere is not solid.
        let got = image(20, |x, y| {
            [9, 9, 9, if x < 10 && y < 10 { 255 } else { 127 }]
        });
        let want = image(20, |x, _| {
            [9, 9, 9, 255].map(|v| v * (5..15).contains(&x) as u8)
        });
        let s = silhouette(&got, &want);
        near(s.iou, 0.2, 1e-12);
        near(s.halo, 0.5, 1e-12);
        near(s.holes, 0.75, 1e-12);
    }

    #[test]
    fn downsampling_averages_premultiplied_blocks() {
        // 4×2 → 2×1: the left block is one opaque red pixel in four, the right block
        // half-covered grey.
        let mut rgba = vec![[0.0f32; 4]; 8];
        rgba[0] = [1.0, 0.0, 0.0, 1.0];
        for i in [2, 3] {
            rgba[i] = [0.5, 0.5, 0.5, 1.0];
        }
        let image = LinearImage {
            width: 4,
            height: 2,
            rgba,
        };
        let small = image.downsample(2);
        assert_eq!((small.width, small.height), (2, 1));
        assert_eq!(small.rgba[0], [0.25, 0.0, 0.0, 0.25]);
        assert_eq!(small.rgba[1], [0.25, 0.25, 0.25, 0.5]);
        assert_eq!(image.downsample(1).rgba, image.rgba);
    }

    #[test]
    fn mean_change_averages_touched_pixels_then_views() {
        // View 0: one of four pixels touched, opaque black against nothing (shown on
        // mid-grey: |0 - 0.5| in every channel); untouched pixels do not count. View 1:
        // identical. Mean over the views: 0.25.
        let image = |first: [f32; 4]| {
            let mut rgba = vec![[0.0f32; 4]; 4];
            rgba[0] = first;
            LinearImage {
                width: 2,
                height: 2,
                rgba,
            }
        };
        let a = vec![image([0.0, 0.0, 0.0, 1.0]), image([0.0, 0.0, 0.0, 1.0])];
        let b = vec![image([0.0; 4]), image([0.0, 0.0, 0.0, 1.0])];
        assert!(
            (mean_change(&a, &b) - 0.25).abs() < 1e-6,
            "{}",
            mean_change(&a, &b)
        );
        assert_eq!(mean_change(&b[..1], &b[..1]), 0.0);
    }

    #[test]
    fn half_transparent_pixel_shows_its_background() {
        // Premultiplied linear (0.25, 0, 0) at coverage 0.5. On black: srgb(0.25) =
        // 1.055·0.25^(1/2.4) − 0.055; on white: srgb(0.75), srgb(0.5), srgb(0.5); grey 0.5
        // is linear 0.214041: srgb(0.25 + 0.5·0.214041), srgb(0.5·0.214041).
        let got = linear(1, vec![[0.25, 0.0, 0.0, 0.5]]);
        let want = linear(1, vec![[0.0; 4]]);
        let expected = [
            (0.0, [0.537_098_73, 0.0, 0.0]),
            (1.0, [0.880_825_02, 0.735_356_98, 0.735_356_98]),
            (0.5, [0.631_870_15, 0.360_780_21, 0.360_780_21]),
        ];
        for (bg, rgb) in expected {
            let shown = got.shown(bg)[0];
            (0..3).for_each(|c| near(shown[c] as f64, rgb[c], 1e-5));
        }
        let black = 0.537_098_73f64.powi(2) / 3.0;
        near(psnr(&got, &want, 0.0), -10.0 * black.log10(), 1e-4);
        let white = (0.119_174_98f64.powi(2) + 2.0 * 0.264_643_02f64.powi(2)) / 3.0;
        near(psnr(&got, &want, 1.0), -10.0 * white.log10(), 1e-4);
    }

    // Expected values from the trainer, in float64 (its float32 gives 0.9253028):
    //   cd train && python3 -c '
    //   import torch, torch.nn.functional as F; from unica_train import splats as s
    //   y, x = torch.meshgrid(torch.arange(32), torch.arange(32), indexing="ij")
    //   a = torch.stack([(7*x + 3*y) % 200 + 30, (x*y) % 97 + 80, (x*x + 2*y) % 150 + 50], -1)
    //   b = a + torch.stack([(5*x + 11*y + 3*c) % 31 - 15 for c in range(3)], -1)
    //   show = lambda k, al: s.srgb(s.linear(k / 255) + (1 - al) * s.linear(torch.tensor(0.5))).double()
    //   s._window = (lambda f: lambda: f().double())(s._window); one = torch.ones(32, 32, 1)
    //   print(s.ssim(show(a, one), show(b, one)).item())  # 0.9253043490032876
    //   r2 = (2*x - 31)**2 + (2*y - 31)**2; ma, mb = (r2 <= 144)[..., None], (r2 <= 256)[..., None]
    //   X = show(a * ma, ma.float()).permute(2, 0, 1)[:, None]
    //   Y = show(b * mb, mb.float()).permute(2, 0, 1)[:, None]
    //   w = s._window()[None, None]; mx, my = F.conv2d(X, w), F.conv2d(Y, w)  # splats.ssim, no .mean()
    //   vx, vy, cxy = F.conv2d(X*X, w) - mx*mx, F.conv2d(Y*Y, w) - my*my, F.conv2d(X*Y, w) - mx*my
    //   m = ((2*mx*my + 1e-4) * (2*cxy + 9e-4) / ((mx*mx + my*my + 1e-4) * (vx + vy + 9e-4))).mean(0)[0]
    //   print(m[(ma | mb)[5:-5, 5:-5, 0]].mean().item())'  # 0.6217591643342124
    #[test]
    fn ssim_matches_the_trainer() {
        let (a, b) = (pattern(false, |_, _| true), pattern(true, |_, _| true));
        near(ssim(&a, &b, 0.5), 0.925_304_349_003_287_6, 1e-5);
        let (a, b) = (pattern(false, disc(144)), pattern(true, disc(256)));
        near(ssim(&a, &b, 0.5), 0.621_759_164_334_212_4, 1e-5);
    }

    #[test]
    fn small_empty_and_out_of_range_inputs_never_panic() {
        let (a, b) = (pattern(false, disc(300)), pattern(true, disc(300)));
        assert_eq!(a.crop(-100, 30, usize::MAX, 9).width, 32);
        assert_eq!(a.crop(40, 0, 5, 5).rgba.len(), 0);
        let (c, d) = (a.crop(10, 10, 6, 40), b.crop(10, 10, 6, 40));
        assert!(ssim(&c, &d, 0.5) < 1.0 && psnr(&c, &d, 0.5).is_finite());
        near(ssim(&c, &c, 0.5), 1.0, 1e-12);
        // Touched only at (3, 8), where no valid window is centred (centres are 5..11): every
        // valid window counts.
        let dot = |v: u8| {
            image(16, move |x, y| {
                [v, 0, 0, 255].map(|c| c * (x == 3 && y == 8) as u8)
            })
        };
        let (e, f) = (dot(200), dot(100));
        let all = ssim_map(&e.shown(0.5), &f.shown(0.5), 6, 6)
            .iter()
            .sum::<f64>()
            / 36.0;
        assert!(all < 0.99, "{all}");
        near(ssim(&e, &f, 0.5), all, 1e-12);
        let empty = linear(0, vec![]);
        assert_eq!(ssim(&empty, &empty, 0.5), 1.0);
        assert_eq!(silhouette(&empty, &empty).iou, 1.0);
    }
}
