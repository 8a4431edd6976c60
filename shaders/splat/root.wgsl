// The root of a frame's drawn points: the mean of its waist points (summed in order),
// written to frame[0..3]. One thread.

#bind p: uniform SplatParams
#bind points: read array<f32>
#bind waist: read array<u32>
#bind frame: read_write array<f32>

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
