// Stored values (Elem) as f32: the refiner's residuals for the splat kernels.

@group(0) @binding(0) var<uniform> p: SplatParams;
@group(0) @binding(1) var<storage, read> x: array<Elem>;
@group(0) @binding(2) var<storage, read_write> y: array<f32>;

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    let i = linear_index(invocation);
    if i >= p.points * p.channels {
        return;
    }
    y[i] = f32(x[i]);
}
