// Nearest-neighbour ×2 upsampling, NCHW: out[n, c, y, x] = in[n, c, y / 2, x / 2].

#import gpu/for_each.wgsl

@group(0) @binding(0) var<uniform> p: UpsampleParams;
@group(0) @binding(1) var<storage, read> x: array<Elem>;
@group(0) @binding(2) var<storage, read_write> y: array<Elem>;

fn count() -> u32 { return p.planes * (2u * p.h_in) * (2u * p.w_in); }

fn each(i: u32) {
    let w_out = 2u * p.w_in;
    let h_out = 2u * p.h_in;
    let ox = i % w_out;
    let oy = (i / w_out) % h_out;
    let plane = i / (w_out * h_out);
    y[i] = x[(plane * p.h_in + oy / 2u) * p.w_in + ox / 2u];
}
