// The PCA coefficients of a frame for GPUs (engine/pca_terms.wgsl), one workgroup per
// component whose WORKGROUP threads split the texels (thread t takes texels t,
// t + WORKGROUP, …), their partial sums then added in thread order by the first. A
// thread per component walking its 3,311 texels alone took 1.3 ms on an NVIDIA H200
// (docs/gpu).

#import engine/pca_terms.wgsl

var<workgroup> partial: array<f32, WORKGROUP>;

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    let k = group_index(invocation);
    let t = invocation.lane;
    let end = select(0u, frame_texels(), k < p.components);
    partial[t] = pca_terms(k, t, WORKGROUP, end);
    workgroupBarrier();
    if t == 0u && k < p.components {
        var sum = 0.0;
        for (var i = 0u; i < WORKGROUP; i++) {
            sum += partial[i];
        }
        coefficients[k] = sum;
    }
}
