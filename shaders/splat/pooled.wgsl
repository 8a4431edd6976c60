// The mean position of each run of `stride` points along an order (the last run may be
// shorter), summed in order: the pooled points of the refiner's coarse stage.

#bind p: uniform SplatParams
#bind unit: read array<f32>
#bind sort: read array<u32>
#bind pooled: read_write array<f32>

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    let g = linear_index(invocation);
    let first = g * p.stride;
    if first >= p.points {
        return;
    }
    let last = min(first + p.stride, p.points);
    var sum = vec3<f32>(0.0);
    for (var r = first; r < last; r++) {
        let i = 3u * sort[r];
        sum += vec3<f32>(unit[i], unit[i + 1u], unit[i + 2u]);
    }
    let mean = sum / f32(last - first);
    pooled[3u * g] = mean.x;
    pooled[3u * g + 1u] = mean.y;
    pooled[3u * g + 2u] = mean.z;
}
