// y[i] = alpha · x[x_offset + i] + beta · z[z_offset + i] for i < len: the DDIM update
// and classifier-free guidance (conditional and null halves of one batch), in f32.

#import gpu/for_each.wgsl

#bind p: uniform AxpbyParams
#bind x, z: read array<Elem>
#bind y: read_write array<Elem>

fn count() -> u32 { return p.len; }

fn each(i: u32) {
    y[i] = Elem(p.alpha * f32(x[p.x_offset + i]) + p.beta * f32(z[p.z_offset + i]));
}
