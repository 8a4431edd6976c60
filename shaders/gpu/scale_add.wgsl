// Example element-wise kernel: y = scale * x + bias, stored as Elem (f32 or f16) and
// computed in f32. Dispatched on a 2-D grid (see gpu::kernel::Grid) so any length fits
// the workgroup limit.

#import gpu/for_each.wgsl

#bind params: uniform ElementwiseParams
#bind x: read array<Elem>
#bind y: read_write array<Elem>

fn count() -> u32 { return params.len; }

fn each(i: u32) {
    y[i] = Elem(params.scale * f32(x[i]) + params.bias);
}
