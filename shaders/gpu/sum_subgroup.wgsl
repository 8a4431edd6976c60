// Example reduction, subgroup path: subgroupAdd inside each subgroup, then shared memory
// across subgroups. Works for any subgroup size from 4 to 128.

#bind params: uniform ReduceParams
#bind x: read array<f32>
#bind total: read_write array<f32>

var<workgroup> partial: array<f32, 64>;

@compute @workgroup_size(256)
fn main(
    @builtin(local_invocation_index) lane: u32,
    @builtin(subgroup_invocation_id) sub_lane: u32,
    @builtin(subgroup_size) sub_size: u32,
) {
    if lane < 64u {
        partial[lane] = 0.0;
    }
    workgroupBarrier();
    var acc = 0.0;
    for (var i = lane; i < params.len; i += 256u) {
        acc += x[i];
    }
    let sub_total = subgroupAdd(acc);
    if sub_lane == 0u {
        partial[lane / sub_size] = sub_total;
    }
    workgroupBarrier();
    if lane == 0u {
        var sum = 0.0;
        for (var s = 0u; s < 256u / sub_size; s++) {
            sum += partial[s];
        }
        total[0] = sum;
    }
}
