// The points normalised about their root: (p - root) · scale + 0.5, one thread per value.

#import gpu/for_each.wgsl

@group(0) @binding(0) var<uniform> p: SplatParams;
@group(0) @binding(1) var<storage, read> points: array<f32>;
@group(0) @binding(2) var<storage, read> frame: array<f32>;
@group(0) @binding(3) var<storage, read_write> unit: array<f32>;

fn count() -> u32 { return 3u * p.points; }

fn each(i: u32) {
    unit[i] = (points[i] - frame[i % 3u]) * p.scale + 0.5;
}
