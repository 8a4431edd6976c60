// The distance of each (point, right or lower neighbour) pair, for the median spacing.

#import gpu/for_each.wgsl

@group(0) @binding(0) var<uniform> p: SplatParams;
@group(0) @binding(1) var<storage, read> points: array<f32>;
@group(0) @binding(2) var<storage, read> pairs: array<vec2<u32>>;
@group(0) @binding(3) var<storage, read_write> distances: array<f32>;

fn point(i: u32) -> vec3<f32> {
    return vec3<f32>(points[3u * i], points[3u * i + 1u], points[3u * i + 2u]);
}

fn count() -> u32 { return p.pairs; }

fn each(m: u32) {
    let d = point(pairs[m].y) - point(pairs[m].x);
    distances[m] = sqrt(d.x * d.x + d.y * d.y + d.z * d.z);
}
