// The points normalised about their root: (p - root) · scale + 0.5, one thread per value.

#import gpu/for_each.wgsl

#bind p: uniform SplatParams
#bind points, frame: read array<f32>
#bind unit: read_write array<f32>

fn count() -> u32 { return 3u * p.points; }

fn each(i: u32) {
    unit[i] = (points[i] - frame[i % 3u]) * p.scale + 0.5;
}
