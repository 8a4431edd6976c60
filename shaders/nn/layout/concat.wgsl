// Concatenation along one axis: a [outer, a_inner] and b [outer, b_inner] become
// y [outer, a_inner + b_inner] (channels of NCHW: inner = C·H·W per sample; frames of
// [B, HW, F, C] rows: inner = F·C).

#import gpu/for_each.wgsl

@group(0) @binding(0) var<uniform> p: ConcatParams;
@group(0) @binding(1) var<storage, read> a: array<Elem>;
@group(0) @binding(2) var<storage, read> b: array<Elem>;
@group(0) @binding(3) var<storage, read_write> y: array<Elem>;

fn count() -> u32 { return p.outer * (p.a_inner + p.b_inner); }

fn each(i: u32) {
    let row = p.a_inner + p.b_inner;
    let o = i / row;
    let k = i % row;
    if k < p.a_inner {
        y[i] = a[o * p.a_inner + k];
    } else {
        y[i] = b[o * p.b_inner + k - p.a_inner];
    }
}
