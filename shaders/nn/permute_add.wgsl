// y = a + permute(x): permute.wgsl's gather (output axis k is input axis perm[k]) added
// to `a` in the same pass, so the attention layers' residual needs no permuted copy.
// The sum is the one add.wgsl makes of `a` and the permuted values. With `has_bias`,
// add_action_bias.wgsl's row of the action table is then added to the rounded sum (the
// spatial attention's residual and the cross-attention's bias in one pass).

@group(0) @binding(0) var<uniform> p: PermuteAddParams;
@group(0) @binding(1) var<storage, read> x: array<Elem>;
@group(0) @binding(2) var<storage, read> a: array<Elem>;
@group(0) @binding(3) var<storage, read> table: array<Elem>;
@group(0) @binding(4) var<storage, read> ids: array<u32>;
@group(0) @binding(5) var<storage, read_write> y: array<Elem>;

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    let i = linear_index(invocation);
    let s = p.shape;
    if i >= s.x * s.y * s.z * s.w {
        return;
    }
    let in_stride = vec4<u32>(s.y * s.z * s.w, s.z * s.w, s.w, 1u);
    let out_shape = vec4<u32>(s[p.perm.x], s[p.perm.y], s[p.perm.z], s[p.perm.w]);
    var rest = i;
    let c3 = rest % out_shape.w;
    rest /= out_shape.w;
    let c2 = rest % out_shape.z;
    rest /= out_shape.z;
    let c1 = rest % out_shape.y;
    let c0 = rest / out_shape.y;
    let src = c0 * in_stride[p.perm.x] + c1 * in_stride[p.perm.y] + c2 * in_stride[p.perm.z] + c3 * in_stride[p.perm.w];
    let sum = Elem(f32(a[i]) + f32(x[src]));
    if p.has_bias == 0u {
        y[i] = sum;
        return;
    }
    let channel = (i / p.hw) % p.channels;
    let sample = i / (p.hw * p.channels * p.frames);
    y[i] = Elem(f32(sum) + f32(table[ids[sample] * p.channels + channel]));
}
