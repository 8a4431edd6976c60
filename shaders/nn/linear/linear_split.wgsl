// Fully connected layer for GPUs (Elem storage, f32 sums): y[b, o] = sum_i act(x[b, i]) *
// weight[o, i] + bias[o], one workgroup per register tile of 4 rows × 4 outputs, its
// WORKGROUP threads splitting the inputs (thread t takes i = t, t + WORKGROUP, …, so
// neighbouring threads load neighbouring values) and summing their partial tiles
// through workgroup memory. linear_tiled.wgsl's thread per tile ran each input in turn:
// about 100 µs a layer on an H200 at the UNet's sizes (docs/gpu). The bias is added to
// the summed tile. Rows and outputs past the end are clamped for the loads and not
// stored. With `p.images` the results go into NCHW images (with an NCHW residual and an
// optional action-table row), stored as linear_cpu.wgsl stores them: the attention
// layers' output projection and the permute back, in one pass (see LinearParams).

#import nn/linear/tile.wgsl

#bind p: uniform LinearParams
#bind x, weight, bias: read array<Elem>
// With `p.has_residual`: added to the rounded result (rows × outputs, or NCHW images
// with `p.images`).
#bind residual: read array<Elem>
// With `p.has_table`: an action table [A, outputs] and the samples' action ids.
#bind table: read array<Elem>
#bind ids: read array<u32>
#bind y: read_write array<Elem>

// Each thread's partial tile (row r at 4t + r).
var<workgroup> partial: array<vec4<f32>, 4u * WORKGROUP>;

// Output `at`: the sum rounded to Elem, plus its residual when there is one.
fn finish(at: u32, v: f32) -> Elem {
    if p.has_residual != 0u {
        return Elem(f32(residual[at]) + f32(Elem(v)));
    }
    return Elem(v);
}

fn act(v: f32) -> f32 {
    if p.input_silu != 0u {
        return v / (1.0 + exp(-v));
    }
    return v;
}

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    // The tile: the workgroup's linear index (those past the end compute nothing and
    // take part in the barrier).
    let i = group_index(invocation);
    let t = invocation.lane;
    let live = i < linear_tile_count(4u);
    let first = linear_tile_at(i, 4u);
    let o0 = first.x;
    let r0 = first.y;
    let last_o = p.outputs - 1u;
    let last_r = p.rows - 1u;
    let wo = vec4<u32>(min(o0, last_o), min(o0 + 1u, last_o), min(o0 + 2u, last_o), min(o0 + 3u, last_o)) * p.inputs;
    let xr = vec4<u32>(min(r0, last_r), min(r0 + 1u, last_r), min(r0 + 2u, last_r), min(r0 + 3u, last_r)) * p.inputs;
    var a0 = vec4<f32>(0.0);
    var a1 = vec4<f32>(0.0);
    var a2 = vec4<f32>(0.0);
    var a3 = vec4<f32>(0.0);
    let end = select(0u, p.inputs, live);
    for (var k = t; k < end; k += WORKGROUP) {
        let w = vec4<f32>(f32(weight[wo.x + k]), f32(weight[wo.y + k]), f32(weight[wo.z + k]), f32(weight[wo.w + k]));
        a0 += act(f32(x[xr.x + k])) * w;
        a1 += act(f32(x[xr.y + k])) * w;
        a2 += act(f32(x[xr.z + k])) * w;
        a3 += act(f32(x[xr.w + k])) * w;
    }
    partial[4u * t] = a0;
    partial[4u * t + 1u] = a1;
    partial[4u * t + 2u] = a2;
    partial[4u * t + 3u] = a3;
    workgroupBarrier();
    // Thread t < 16 sums output (row t / 4, output t % 4) over the threads, in order.
    if !live || t >= 16u {
        return;
    }
    let r = t / 4u;
    let c = t % 4u;
    var sum = 0.0;
    for (var k = 0u; k < WORKGROUP; k++) {
        sum += partial[4u * k + r][c];
    }
    let row = r0 + r;
    let o = o0 + c;
    if row >= p.rows || o >= p.outputs {
        return;
    }
    // Row `row`, output o: at row · outputs + o, or with `p.images` at pixel q of channel
    // o of image n·F + f for token row (n·HW + q)·F + f.
    let frames = max(p.images, 1u);
    let rest = row / frames;
    let image = (rest / p.hw) * frames + row % frames;
    let at = select(row * p.outputs + o, (image * p.outputs + o) * p.hw + rest % p.hw, p.images != 0u);
    var out = finish(at, f32(bias[o]) + sum);
    if p.has_table != 0u {
        let action = ids[image / max(p.table_frames, 1u)];
        out = Elem(f32(out) + f32(table[action * p.outputs + o]));
    }
    y[at] = out;
}
