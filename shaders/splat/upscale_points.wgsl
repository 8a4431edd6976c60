// The fine level's rows upscaled from the coarse points' rows: upscale_map.wgsl's
// arithmetic evaluated at the fine points' pixels only, reading the coarse rows through
// the 128² map's point index (-1 on the background) instead of a scattered map. Per fine
// point: the bilinear weights of its pixel's four coarse neighbours (half-pixel centres,
// edges clamped), the mask-weighted values summed over the corners in order and divided
// by the weighted mask; 0 where that is at most 0.25 (the fine pixels are those above it,
// so none). `channels` values a row, in and out. Upscaling the whole map and gathering
// the points from it took 6 + 6 dispatches over 65,536 pixels a frame at level 256.

#import gpu/for_each.wgsl

#bind p: uniform SplatParams
#bind rows: read array<f32>
#bind index: read array<i32>
#bind pixels: read array<u32>
#bind out: read_write array<f32>

fn count() -> u32 { return p.points; }

fn each(j: u32) {
    let size = COARSE * p.factor;
    let q = pixels[j];
    let sx = clamp((f32(q % size) + 0.5) / f32(p.factor) - 0.5, 0.0, f32(COARSE - 1u));
    let sy = clamp((f32(q / size) + 0.5) / f32(p.factor) - 0.5, 0.0, f32(COARSE - 1u));
    let x0 = u32(floor(sx));
    let y0 = u32(floor(sy));
    let x1 = min(x0 + 1u, COARSE - 1u);
    let y1 = min(y0 + 1u, COARSE - 1u);
    let fx = sx - f32(x0);
    let fy = sy - f32(y0);
    let corners = array<i32, 4>(index[y0 * COARSE + x0], index[y0 * COARSE + x1], index[y1 * COARSE + x0],
                                index[y1 * COARSE + x1]);
    let weights = array<f32, 4>((1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy);
    var wm = array<f32, 4>();
    var m = 0.0;
    for (var k = 0u; k < 4u; k++) {
        wm[k] = weights[k] * select(0.0, 1.0, corners[k] >= 0i);
        m += wm[k];
    }
    for (var c = 0u; c < p.channels; c++) {
        var v = 0.0;
        for (var k = 0u; k < 4u; k++) {
            var x = 0.0;
            if corners[k] >= 0i {
                x = rows[u32(corners[k]) * p.channels + c];
            }
            v += wm[k] * x;
        }
        out[j * p.channels + c] = select(0.0, v / m, m > 0.25);
    }
}
