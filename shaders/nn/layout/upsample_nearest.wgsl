// Nearest-neighbour ×2 upsampling, NCHW: out[n, c, y, x] = in[n, c, y / 2, x / 2].

#import gpu/for_each.wgsl

#bind p: uniform UpsampleParams
#bind x: read array<Elem>
#bind y: read_write array<Elem>

fn count() -> u32 { return p.planes * (2u * p.h_in) * (2u * p.w_in); }

fn each(i: u32) {
    let w_out = 2u * p.w_in;
    let h_out = 2u * p.h_in;
    let ox = i % w_out;
    let oy = (i / w_out) % h_out;
    let plane = i / (w_out * h_out);
    y[i] = x[(plane * p.h_in + oy / 2u) * p.w_in + ox / 2u];
}
