// Fully connected layer for CPU drivers over plain rows (Elem storage, f32 sums; no
// images, no action table) whose outputs are a multiple of 4 (host-checked), in
// cpu_tile.wgsl's register tiles: four outputs of a row are one vec4 store, and their
// residual one vec4 load. On lavapipe a storage access is a loop over the SIMD lanes
// for every value it moves, so linear_cpu.wgsl's one-value stores took about a third
// of the refiner's linear layers (docs/performance.md, "Stores and fetches"). The same
// sums and roundings as linear_cpu.wgsl, so the same bits.

#import nn/linear/cpu_tile.wgsl

#bind p: uniform LinearParams
#bind x, weight: texture_2d<f32>
#bind bias: read array<Elem>
// With `p.has_residual`: [rows, outputs] added to the rounded result.
#bind residual: read array<vec4<Elem>>
// With `p.gather_rows`: the input rows.
#bind ids: read array<u32>
// With `p.norm_rows`: the layer norm's gamma and beta.
#bind gamma, beta: texture_2d<f32>
#bind y: read_write array<vec4<Elem>>

// Outputs o0 … o0 + 3 of `row` (none past the last row or output).
fn store(row: u32, o0: u32, v: vec4<f32>) {
    if row >= p.rows || o0 >= p.outputs {
        return;
    }
    let at = (row * p.outputs + o0) / 4u;
    var out = vec4<Elem>(v);
    if p.has_residual != 0u {
        out = vec4<Elem>(vec4<f32>(residual[at]) + vec4<f32>(out));
    }
    y[at] = out;
}
