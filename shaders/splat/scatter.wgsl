// Three channels of per-point rows (`channels` values each, from `first`; channels past
// the end are 0) into a [3, size, size] map at the points' pixels; the background keeps
// what it has (0).

#import gpu/for_each.wgsl

#bind p: uniform SplatParams
#bind rows: read array<f32>
#bind pixels: read array<u32>
#bind map: read_write array<f32>

fn count() -> u32 { return p.points; }

fn each(i: u32) {
    for (var k = 0u; k < 3u; k++) {
        var v = 0.0;
        if p.first + k < p.channels {
            v = rows[i * p.channels + p.first + k];
        }
        map[k * p.plane + pixels[i]] = v;
    }
}
