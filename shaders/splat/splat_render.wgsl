// Front-to-back blending, one workgroup per 16×16 tile and one thread per pixel: the
// tile's splats (sorted by depth) are loaded 256 at a time into shared memory; each pixel
// adds α·T·colour (α = min(0.99, opacity·e^power), skipped below 1/255) and stops once
// its transmittance would fall below 1e-4; the workgroup stops when every pixel has.
// Output: linear RGBA (alpha = coverage) over the background.
//
// The walk over a batch is unrolled 8 splats an iteration: lavapipe ends every loop of
// an invocation once all of its loops together have run 65,535 iterations (Mesa's
// LP_MAX_TGSI_LOOP_ITERATIONS), and a tile of the Witch's level-1024 splats at 128²
// holds up to 75,102 sort entries (tests/splat.rs). Unrolled, a tile may hold
// 8 · 65,535 entries less the batches' own iterations, more than any splat count the
// project draws (each splat enters a tile once).

#bind f: uniform RasterView
#bind projected: read array<ProjectedSplat>
#bind values: read array<u32>
#bind ranges: read array<vec2<u32>>
#bind image: read_write array<vec4<f32>>

#import splat/splat_alpha.wgsl

var<workgroup> batch: array<ProjectedSplat, 256>;
var<workgroup> finished: atomic<u32>;
var<workgroup> all_finished: u32;

const UNROLL: u32 = 8u;

struct Pixel {
    color: vec3<f32>,
    transmittance: f32,
    done: bool,
}

// Splat `k` of the batch (if k < n) over the pixel at `at`, unless it has stopped.
fn blend(k: u32, n: u32, at: vec2<f32>, pix: ptr<function, Pixel>) {
    if k >= n || (*pix).done {
        return;
    }
    let p = batch[k];
    let alpha = splat_alpha(p, p.center_depth.xy - at);
    if alpha == 0.0 {
        return;
    }
    let t = (*pix).transmittance;
    let next = t * (1.0 - alpha);
    if next < 1e-4 {
        (*pix).done = true;
        atomicAdd(&finished, 1u);
        return;
    }
    (*pix).color += p.color.xyz * alpha * t;
    (*pix).transmittance = next;
}

@compute @workgroup_size(16, 16)
fn main(invocation: Invocation) {
    let tile = group_index(invocation);
    let lane = invocation.lane;
    let tiles = f.tiles_x * f.tiles_y;
    let valid_tile = tile < tiles;
    let tx = tile % f.tiles_x;
    let ty = tile / f.tiles_x;
    let x = tx * TILE + lane % TILE;
    let y = ty * TILE + lane / TILE;
    let inside = valid_tile && x < f.width && y < f.height;
    let pixel = vec2<f32>(f32(x) + 0.5, f32(y) + 0.5);
    var range = vec2<u32>(0u, 0u);
    if valid_tile {
        range = ranges[tile];
    }
    var done = !inside;
    var pix = Pixel(vec3<f32>(0.0), 1.0, done);
    if lane == 0u {
        atomicStore(&finished, 0u);
    }
    workgroupBarrier();
    if done {
        atomicAdd(&finished, 1u);
    }
    for (var start = range.x; start < range.y; start += 256u) {
        workgroupBarrier();
        if lane == 0u {
            all_finished = atomicLoad(&finished);
        }
        if workgroupUniformLoad(&all_finished) == 256u {
            break;
        }
        if start + lane < range.y {
            batch[lane] = projected[values[start + lane]];
        }
        workgroupBarrier();
        let n = min(256u, range.y - start);
        for (var k = 0u; k < n && !done; k += UNROLL) {
            blend(k, n, pixel, &pix);
            blend(k + 1u, n, pixel, &pix);
            blend(k + 2u, n, pixel, &pix);
            blend(k + 3u, n, pixel, &pix);
            blend(k + 4u, n, pixel, &pix);
            blend(k + 5u, n, pixel, &pix);
            blend(k + 6u, n, pixel, &pix);
            blend(k + 7u, n, pixel, &pix);
            done = pix.done;
        }
    }
    if inside {
        image[y * f.width + x] = vec4<f32>(pix.color + f.background.xyz * pix.transmittance, 1.0 - pix.transmittance);
    }
}
