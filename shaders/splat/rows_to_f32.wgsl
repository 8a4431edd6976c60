// Stored values (Elem) as f32: the refiner's residuals for the splat kernels.

#import gpu/for_each.wgsl

@group(0) @binding(0) var<uniform> p: SplatParams;
@group(0) @binding(1) var<storage, read> x: array<Elem>;
@group(0) @binding(2) var<storage, read_write> y: array<f32>;

fn count() -> u32 { return p.points * p.channels; }

fn each(i: u32) {
    y[i] = f32(x[i]);
}
