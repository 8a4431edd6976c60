// Three channels of a [3, size, size] map at the points' pixels into per-point rows
// (`channels` values each, from `first`; channels past the end are not written).

#import gpu/for_each.wgsl

#bind p: uniform SplatParams
#bind map: read array<f32>
#bind pixels: read array<u32>
#bind rows: read_write array<f32>

fn count() -> u32 { return p.points; }

fn each(i: u32) {
    for (var k = 0u; k < 3u; k++) {
        if p.first + k < p.channels {
            rows[i * p.channels + p.first + k] = map[k * p.plane + pixels[i]];
        }
    }
}
