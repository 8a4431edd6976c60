// y = a + permute(x): permute.wgsl's gather (output axis k is input axis perm[k]) added
// to `a` in the same pass, so the attention layers' residual needs no permuted copy.
// The sum is the one add.wgsl makes of `a` and the permuted values.

@group(0) @binding(0) var<uniform> p: PermuteParams;
@group(0) @binding(1) var<storage, read> x: array<Elem>;
@group(0) @binding(2) var<storage, read> a: array<Elem>;
@group(0) @binding(3) var<storage, read_write> y: array<Elem>;

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
    y[i] = Elem(f32(a[i]) + f32(x[src]));
}
