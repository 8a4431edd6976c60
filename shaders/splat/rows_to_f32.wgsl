// Stored values (Elem) as f32: the refiner's residuals for the splat kernels.

#import gpu/for_each.wgsl

#bind p: uniform SplatParams
#bind x: read array<Elem>
#bind y: read_write array<f32>

fn count() -> u32 { return p.points * p.channels; }

fn each(i: u32) {
    y[i] = f32(x[i]);
}
