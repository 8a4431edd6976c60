// 2-D convolution, NCHW, stored as Elem (f32 or f16), summed in f32: one thread per output value, summing input channels and the
// kernel window (zero padding). Weights [c_out, c_in, k, k], optional bias [c_out].

@group(0) @binding(0) var<uniform> p: Conv2dParams;
@group(0) @binding(1) var<storage, read> x: array<Elem>;
@group(0) @binding(2) var<storage, read> weight: array<Elem>;
@group(0) @binding(3) var<storage, read> bias: array<Elem>;
@group(0) @binding(4) var<storage, read_write> y: array<Elem>;

@compute @workgroup_size(64)
fn main(
    @builtin(workgroup_id) group: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
    @builtin(local_invocation_index) lane: u32,
) {
    let i = (group.x + group.y * groups.x) * 64u + lane;
    let total = p.batch * p.c_out * p.h_out * p.w_out;
    if i >= total {
        return;
    }
    let ox = i % p.w_out;
    let oy = (i / p.w_out) % p.h_out;
    let co = (i / (p.w_out * p.h_out)) % p.c_out;
    let n = i / (p.w_out * p.h_out * p.c_out);
    var acc = 0.0;
    if p.has_bias != 0u {
        acc = f32(bias[co]);
    }
    for (var ci = 0u; ci < p.c_in; ci++) {
        let x_base = (n * p.c_in + ci) * p.h_in * p.w_in;
        let w_base = (co * p.c_in + ci) * p.kernel * p.kernel;
        for (var ky = 0u; ky < p.kernel; ky++) {
            let iy = i32(oy * p.stride + ky) - i32(p.pad);
            if iy < 0 || iy >= i32(p.h_in) {
                continue;
            }
            for (var kx = 0u; kx < p.kernel; kx++) {
                let ix = i32(ox * p.stride + kx) - i32(p.pad);
                if ix < 0 || ix >= i32(p.w_in) {
                    continue;
                }
                acc += f32(x[x_base + u32(iy) * p.w_in + u32(ix)]) * f32(weight[w_base + ky * p.kernel + kx]);
            }
        }
    }
    y[i] = Elem(acc);
}
