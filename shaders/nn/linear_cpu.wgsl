// Fully connected layer for CPU drivers (Elem storage, f32 sums): linear_tiled.wgsl's
// 4 rows × 4 outputs of y[b, o] = sum_i act(x[b, i]) * weight[o, i] + bias[o] per
// invocation, with every load a vec4 along the contiguous input axis (inputs a multiple
// of 4, host-checked): 8 loads per 64 multiply-adds. The four weight vectors are
// transposed in registers, so each sum still runs over i in order from the bias, as
// linear.wgsl's does. Rows and outputs past the end are clamped for the loads and not
// stored.

@group(0) @binding(0) var<uniform> p: LinearParams;
@group(0) @binding(1) var<storage, read> x: array<vec4<Elem>>;
@group(0) @binding(2) var<storage, read> weight: array<vec4<Elem>>;
@group(0) @binding(3) var<storage, read> bias: array<Elem>;
// With `p.has_residual`: added to the rounded result (rows × outputs).
@group(0) @binding(4) var<storage, read> residual: array<Elem>;
@group(0) @binding(5) var<storage, read_write> y: array<Elem>;

// Output `at`: the sum rounded to Elem, plus its residual when there is one.
fn finish(at: u32, v: f32) -> Elem {
    if p.has_residual != 0u {
        return Elem(f32(residual[at]) + f32(Elem(v)));
    }
    return Elem(v);
}

fn act(v: vec4<Elem>) -> vec4<f32> {
    let f = vec4<f32>(v);
    if p.input_silu != 0u {
        return f / (1.0 + exp(-f));
    }
    return f;
}

fn store(row: u32, o0: u32, v: vec4<f32>) {
    if row >= p.rows {
        return;
    }
    for (var c = 0u; c < 4u; c++) {
        if o0 + c < p.outputs {
            y[row * p.outputs + o0 + c] = finish(row * p.outputs + o0 + c, v[c]);
        }
    }
}

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    let i = linear_index(invocation);
    let out_tiles = (p.outputs + 3u) / 4u;
    let row_tiles = (p.rows + 3u) / 4u;
    if i >= out_tiles * row_tiles {
        return;
    }
    let o0 = (i % out_tiles) * 4u;
    let r0 = (i / out_tiles) * 4u;
    let last_o = p.outputs - 1u;
    let last_r = p.rows - 1u;
    let quads = p.inputs / 4u;
    let wo = vec4<u32>(min(o0, last_o), min(o0 + 1u, last_o), min(o0 + 2u, last_o), min(o0 + 3u, last_o)) * quads;
    let xr = vec4<u32>(min(r0, last_r), min(r0 + 1u, last_r), min(r0 + 2u, last_r), min(r0 + 3u, last_r)) * quads;
    let b = vec4<f32>(
        f32(bias[min(o0, last_o)]),
        f32(bias[min(o0 + 1u, last_o)]),
        f32(bias[min(o0 + 2u, last_o)]),
        f32(bias[min(o0 + 3u, last_o)]),
    );
    var a0 = b;
    var a1 = b;
    var a2 = b;
    var a3 = b;
    for (var k = 0u; k < quads; k++) {
        let x0 = act(x[xr.x + k]);
        let x1 = act(x[xr.y + k]);
        let x2 = act(x[xr.z + k]);
        let x3 = act(x[xr.w + k]);
        let w0 = vec4<f32>(weight[wo.x + k]);
        let w1 = vec4<f32>(weight[wo.y + k]);
        let w2 = vec4<f32>(weight[wo.z + k]);
        let w3 = vec4<f32>(weight[wo.w + k]);
        // Input 4k + j of the four outputs.
        let t0 = vec4<f32>(w0.x, w1.x, w2.x, w3.x);
        let t1 = vec4<f32>(w0.y, w1.y, w2.y, w3.y);
        let t2 = vec4<f32>(w0.z, w1.z, w2.z, w3.z);
        let t3 = vec4<f32>(w0.w, w1.w, w2.w, w3.w);
        a0 += x0.x * t0;
        a1 += x1.x * t0;
        a2 += x2.x * t0;
        a3 += x3.x * t0;
        a0 += x0.y * t1;
        a1 += x1.y * t1;
        a2 += x2.y * t1;
        a3 += x3.y * t1;
        a0 += x0.z * t2;
        a1 += x1.z * t2;
        a2 += x2.z * t2;
        a3 += x3.z * t2;
        a0 += x0.w * t3;
        a1 += x1.w * t3;
        a2 += x2.w * t3;
        a3 += x3.w * t3;
    }
    store(r0, o0, a0);
    store(r0 + 1u, o0, a1);
    store(r0 + 2u, o0, a2);
    store(r0 + 3u, o0, a3);
}
