// Fully connected layer (Elem storage, f32 sums): y[b, o] = sum_i act(x[b, i]) * weight[o, i] + bias[o], where
// act is SiLU when `input_silu` is set (the embedding projections) and identity otherwise.

@group(0) @binding(0) var<uniform> p: LinearParams;
@group(0) @binding(1) var<storage, read> x: array<Elem>;
@group(0) @binding(2) var<storage, read> weight: array<Elem>;
@group(0) @binding(3) var<storage, read> bias: array<Elem>;
@group(0) @binding(4) var<storage, read_write> y: array<Elem>;

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    let i = linear_index(invocation);
    if i >= p.rows * p.outputs {
        return;
    }
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
    y[i] = Elem(acc);
}
