// Fully connected layer (Elem storage, f32 sums): y[b, o] = sum_i act(x[b, i]) * weight[o, i] + bias[o], where
// act is SiLU when `input_silu` is set (the embedding projections) and identity otherwise.

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

fn count() -> u32 { return p.rows * p.outputs; }

fn each(i: u32) {
    let o = i % p.outputs;
    let row = i / p.outputs;
    var acc = f32(bias[o]);
    for (var k = 0u; k < p.inputs; k++) {
        var v = f32(x[row * p.inputs + k]);
        if p.input_silu != 0u {
            v = v / (1.0 + exp(-v));
        }
        acc += v * f32(weight[o * p.inputs + k]);
    }
    y[i] = finish(i, acc);
}
