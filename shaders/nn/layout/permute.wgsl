// Permutes the axes of a 4-D tensor (output axis k is input axis perm[k]) and adds to it:
// moves images between NCHW and token-major layouts for the attention layers, with their
// residual (`a`), frame positions (`rows`) and action bias (`table`) in the same pass.
// Each addend is added to the sum rounded to Elem, as add.wgsl and add_action_bias.wgsl
// would add it after a plain permute (see PermuteParams).

#import gpu/for_each.wgsl

#bind p: uniform PermuteParams
#bind x, a, rows, table: read array<Elem>
#bind ids: read array<u32>
#bind y: read_write array<Elem>

fn count() -> u32 { return p.shape.x * p.shape.y * p.shape.z * p.shape.w; }

fn each(i: u32) {
    let s = p.shape;
    let in_stride = vec4<u32>(s.y * s.z * s.w, s.z * s.w, s.w, 1u);
    let out_shape = vec4<u32>(s[p.perm.x], s[p.perm.y], s[p.perm.z], s[p.perm.w]);
    var rest = i;
    let c3 = rest % out_shape.w;
    rest /= out_shape.w;
    let c2 = rest % out_shape.z;
    rest /= out_shape.z;
    let c1 = rest % out_shape.y;
    let c0 = rest / out_shape.y;
    let src = c0 * in_stride[p.perm.x] + c1 * in_stride[p.perm.y] + c2 * in_stride[p.perm.z] + c3 * in_stride[p.perm.w];
    var sum = x[src];
    if p.has_a != 0u {
        sum = Elem(f32(a[i]) + f32(sum));
    }
    if p.has_rows != 0u {
        sum = Elem(f32(sum) + f32(rows[p.rows_offset + i % p.rows_len]));
    }
    if p.has_bias != 0u {
        let channel = (i / p.hw) % p.channels;
        let sample = i / (p.hw * p.channels * p.frames);
        sum = Elem(f32(sum) + f32(table[ids[sample] * p.channels + channel]));
    }
    y[i] = sum;
}
