// Fully connected layer in register tiles (Elem storage, f32 sums): each invocation
// computes 4 rows × 4 outputs of y[b, o] = sum_i act(x[b, i]) * weight[o, i] + bias[o],
// so every loaded input value is used 4 times and every weight 4 times (on a CPU driver
// the caches do the rest; on a GPU it quarters the loads). The sums run over i in order
// from the bias, as linear.wgsl's do. Rows and outputs past the end are clamped for the
// loads and not stored.

#import nn/linear/tile.wgsl
#import gpu/for_each.wgsl

#bind p: uniform LinearParams
#bind x, weight, bias: read array<Elem>
// With `p.has_residual`: added to the rounded result (rows × outputs).
#bind residual: read array<Elem>
#bind y: read_write array<Elem>

// Output `at`: the sum rounded to Elem, plus its residual when there is one.
fn finish(at: u32, v: f32) -> Elem {
    if p.has_residual != 0u {
        return Elem(f32(residual[at]) + f32(Elem(v)));
    }
    return Elem(v);
}

fn act(v: f32) -> f32 {
    if p.input_silu != 0u {
        return v / (1.0 + exp(-v));
    }
    return v;
}

fn count() -> u32 { return linear_tile_count(4u); }

fn each(i: u32) {
    let first = linear_tile_at(i, 4u);
    let o0 = first.x;
    let r0 = first.y;
    let last_o = p.outputs - 1u;
    let last_r = p.rows - 1u;
    let wo = vec4<u32>(min(o0, last_o), min(o0 + 1u, last_o), min(o0 + 2u, last_o), min(o0 + 3u, last_o)) * p.inputs;
    let xr = vec4<u32>(min(r0, last_r), min(r0 + 1u, last_r), min(r0 + 2u, last_r), min(r0 + 3u, last_r)) * p.inputs;
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
    for (var k = 0u; k < p.inputs; k++) {
        let w = vec4<f32>(f32(weight[wo.x + k]), f32(weight[wo.y + k]), f32(weight[wo.z + k]), f32(weight[wo.w + k]));
        a0 += act(f32(x[xr.x + k])) * w;
        a1 += act(f32(x[xr.y + k])) * w;
        a2 += act(f32(x[xr.z + k])) * w;
        a3 += act(f32(x[xr.w + k])) * w;
    }
    let acc = array<vec4<f32>, 4>(a0, a1, a2, a3);
    for (var r = 0u; r < 4u; r++) {
        let row = r0 + r;
        if row >= p.rows {
            break;
        }
        for (var c = 0u; c < 4u; c++) {
            let o = o0 + c;
            if o < p.outputs {
                y[row * p.outputs + o] = finish(row * p.outputs + o, acc[r][c]);
            }
        }
    }
}
