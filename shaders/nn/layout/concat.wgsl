// Concatenation along one axis: a [outer, a_inner] and b [outer, b_inner] become
// y [outer, a_inner + b_inner] (channels of NCHW: inner = C·H·W per sample; frames of
// [B, HW, F, C] rows: inner = F·C).

#import gpu/for_each.wgsl

#bind p: uniform ConcatParams
#bind a, b: read array<Elem>
#bind y: read_write array<Elem>

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
