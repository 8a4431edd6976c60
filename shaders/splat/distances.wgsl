// The distance of each (point, right or lower neighbour) pair, for the median spacing.

#import gpu/for_each.wgsl

#bind p: uniform SplatParams
#bind points: read array<f32>
#bind pairs: read array<vec2<u32>>
#bind distances: read_write array<f32>

fn point(i: u32) -> vec3<f32> {
    return vec3<f32>(points[3u * i], points[3u * i + 1u], points[3u * i + 2u]);
}

fn count() -> u32 { return p.pairs; }

fn each(m: u32) {
    let d = point(pairs[m].y) - point(pairs[m].x);
    distances[m] = sqrt(d.x * d.x + d.y * d.y + d.z * d.z);
}
