// Group normalisation of NCHW (Elem storage, f32 statistics) with a per-channel affine and an optional fused SiLU.
// One workgroup per (sample, group): a shared-memory reduction of the mean and variance
// (two passes over the data, exact), then every thread writes its share.

@group(0) @binding(0) var<uniform> p: GroupNormParams;
@group(0) @binding(1) var<storage, read> x: array<Elem>;
@group(0) @binding(2) var<storage, read> gamma: array<Elem>;
@group(0) @binding(3) var<storage, read> beta: array<Elem>;
@group(0) @binding(4) var<storage, read_write> y: array<Elem>;

var<workgroup> partial: array<f32, 64>;

fn reduce(lane: u32, value: f32) -> f32 {
    partial[lane] = value;
    workgroupBarrier();
    for (var stride = 32u; stride > 0u; stride /= 2u) {
        if lane < stride {
            partial[lane] += partial[lane + stride];
        }
        workgroupBarrier();
    }
    let total = partial[0];
    workgroupBarrier();
    return total;
}

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) group: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) lane: u32,
) {
    let id = group.x + group.y * groups.x;
    if id >= p.batch * p.groups {
        return;
    }
    let per_group = p.channels / p.groups;
    let count = per_group * p.hw;
    let base = id * count; // (n, g) blocks are contiguous in NCHW
    var sum = 0.0;
    for (var i = lane; i < count; i += 64u) {
        sum += f32(x[base + i]);
    }
    let mean = reduce(lane, sum) / f32(count);
    var squares = 0.0;
    for (var i = lane; i < count; i += 64u) {
        let d = f32(x[base + i]) - mean;
        squares += d * d;
    }
    let inv_std = inverseSqrt(reduce(lane, squares) / f32(count) + p.eps);
    let first_channel = (id % p.groups) * per_group;
    for (var i = lane; i < count; i += 64u) {
        let c = first_channel + i / p.hw;
        var v = (f32(x[base + i]) - mean) * inv_std * f32(gamma[c]) + f32(beta[c]);
        if p.silu != 0u {
            v = v / (1.0 + exp(-v));
        }
        y[base + i] = Elem(v);
    }
}
