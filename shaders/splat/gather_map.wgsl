// Three channels of a [3, size, size] map at the points' pixels into per-point rows
// (`channels` values each, from `first`; channels past the end are not written).

@group(0) @binding(0) var<uniform> p: SplatParams;
@group(0) @binding(1) var<storage, read> map: array<f32>;
@group(0) @binding(2) var<storage, read> pixels: array<u32>;
@group(0) @binding(3) var<storage, read_write> rows: array<f32>;

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    let i = linear_index(invocation);
    if i >= p.points {
        return;
    }
    for (var k = 0u; k < 3u; k++) {
        if p.first + k < p.channels {
            rows[i * p.channels + p.first + k] = map[k * p.plane + pixels[i]];
        }
    }
}
