// The root of a frame's drawn points: the mean of its waist points (summed in order),
// written to frame[0..3]. One thread.

@group(0) @binding(0) var<uniform> p: SplatParams;
@group(0) @binding(1) var<storage, read> points: array<f32>;
@group(0) @binding(2) var<storage, read> waist: array<u32>;
@group(0) @binding(3) var<storage, read_write> frame: array<f32>;

@compute @workgroup_size(1)
fn main() {
    var root = vec3<f32>(0.0);
    for (var w = 0u; w < p.waist; w++) {
        let q = 3u * waist[w];
        root += vec3<f32>(points[q], points[q + 1u], points[q + 2u]);
    }
    root /= f32(p.waist);
    frame[0] = root.x;
    frame[1] = root.y;
    frame[2] = root.z;
}
