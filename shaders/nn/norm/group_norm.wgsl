// Group normalisation of NCHW (Elem storage, f32 statistics) with a per-channel affine and an optional fused SiLU.
// One workgroup of THREADS per (sample, group): a shared-memory reduction of the mean and
// variance (two passes over the data, exact), then every thread writes its share. With `p.tokens`
// (F > 0) the values are stored as token rows [N, HW, F, C] instead, plus optional frame
// positions, as group_norm_serial.wgsl stores them: the attention layers' permute, done
// by the stores (see GroupNormParams).

#bind p: uniform GroupNormParams
#bind x, gamma, beta: read array<Elem>
// With `p.has_rows`: frame positions added to the token rows.
#bind rows: read array<Elem>
#bind y: read_write array<Elem>

var<workgroup> partial: array<f32, THREADS>;

fn reduce(lane: u32, value: f32) -> f32 {
    partial[lane] = value;
    workgroupBarrier();
    for (var stride = THREADS / 2u; stride > 0u; stride /= 2u) {
        if lane < stride {
            partial[lane] += partial[lane + stride];
        }
        workgroupBarrier();
    }
    let total = partial[0];
    workgroupBarrier();
    return total;
}

@compute @workgroup_size(THREADS)
fn main(invocation: Invocation) {
    let id = group_index(invocation);
    let lane = invocation.lane;
    if id >= p.batch * p.groups {
        return;
    }
    let per_group = p.channels / p.groups;
    let count = per_group * p.hw;
    let base = id * count; // (n, g) blocks are contiguous in NCHW
    var sum = 0.0;
    for (var i = lane; i < count; i += THREADS) {
        sum += f32(x[base + i]);
    }
    let mean = reduce(lane, sum) / f32(count);
    var squares = 0.0;
    for (var i = lane; i < count; i += THREADS) {
        let d = f32(x[base + i]) - mean;
        squares += d * d;
    }
    let inv_std = inverseSqrt(reduce(lane, squares) / f32(count) + p.eps);
    let first_channel = (id % p.groups) * per_group;
    // Token rows: image n·F + f's pixel q is row (n·HW + q)·F + f.
    let image = id / p.groups;
    let frames = max(p.tokens, 1u);
    let f = image % frames;
    let first_row = ((image / frames) * p.hw * frames + f) * p.channels;
    for (var i = lane; i < count; i += THREADS) {
        let c = first_channel + i / p.hw;
        var v = (f32(x[base + i]) - mean) * inv_std * f32(gamma[c]) + f32(beta[c]);
        if p.silu != 0u {
            v = v / (1.0 + exp(-v));
        }
        if p.tokens == 0u {
            y[base + i] = Elem(v);
        } else {
            // Rounded to Elem, then the position added and rounded again: the norm's
            // store and the permute's add.
            var out = f32(Elem(v));
            if p.has_rows != 0u {
                out += f32(rows[p.rows_offset + f * p.channels + c]);
            }
            y[first_row + (i % p.hw) * frames * p.channels + c] = Elem(out);
        }
    }
}
