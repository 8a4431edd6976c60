// Three channels of a [3, size, size] map at the points' pixels into per-point rows
// (`channels` values each, from `first`; channels past the end are not written).

#import gpu/for_each.wgsl

@group(0) @binding(0) var<uniform> p: SplatParams;
@group(0) @binding(1) var<storage, read> map: array<f32>;
@group(0) @binding(2) var<storage, read> pixels: array<u32>;
@group(0) @binding(3) var<storage, read_write> rows: array<f32>;

fn count() -> u32 { return p.points; }

fn each(i: u32) {
    for (var k = 0u; k < 3u; k++) {
        if p.first + k < p.channels {
            rows[i * p.channels + p.first + k] = map[k * p.plane + pixels[i]];
        }
    }
}
