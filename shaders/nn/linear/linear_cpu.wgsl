// Fully connected layer for CPU drivers (Elem storage, f32 sums) in cpu_tile.wgsl's
// register tiles, stored one value at a time. With `p.images` the results go into NCHW
// images (with an NCHW residual and an optional action-table row): the attention
// layers' output projection and the permute back, in one pass (see LinearParams).
// Plain rows whose outputs fill whole vec4s take linear_rows_cpu.wgsl instead.

#import nn/linear/cpu_tile.wgsl

#bind p: uniform LinearParams
#bind x, weight: texture_2d<f32>
#bind bias: read array<Elem>
// With `p.has_residual`: added to the rounded result (rows × outputs, or NCHW images
// with `p.images`).
#bind residual: read array<Elem>
// With `p.has_table`: an action table [A, outputs] and the samples' action ids.
#bind table: read array<Elem>
// The action ids (with `p.has_table`), or the input rows (with `p.gather_rows`).
#bind ids: read array<u32>
// With `p.norm_rows`: the layer norm's gamma and beta.
#bind gamma, beta: texture_2d<f32>
#bind y: read_write array<Elem>

// Output `at`: the sum rounded to Elem, plus its residual when there is one.
fn finish(at: u32, v: f32) -> Elem {
    if p.has_residual != 0u {
        return Elem(f32(residual[at]) + f32(Elem(v)));
    }
    return Elem(v);
}

// Outputs o0 … o0 + 3 of `row`: at row · outputs + o, or with `p.images` at pixel q of
// channel o of image n·F + f for token row (n·HW + q)·F + f.
fn store(row: u32, o0: u32, v: vec4<f32>) {
    if row >= p.rows {
        return;
    }
    let frames = max(p.images, 1u);
    let rest = row / frames;
    let image = (rest / p.hw) * frames + row % frames;
    let into_images = p.images != 0u;
    let first = select(row * p.outputs, image * p.outputs * p.hw + rest % p.hw, into_images);
    let step = select(1u, p.hw, into_images);
    let action = ids[image / max(p.table_frames, 1u)];
    for (var c = 0u; c < 4u; c++) {
        let o = o0 + c;
        if o < p.outputs {
            let at = first + o * step;
            var out = finish(at, v[c]);
            if p.has_table != 0u {
                out = Elem(f32(out) + f32(table[action * p.outputs + o]));
            }
            y[at] = out;
        }
    }
}
