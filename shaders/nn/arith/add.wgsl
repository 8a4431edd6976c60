// Sums: y[i] = a[i] + b[b_offset + (i / per_value) % b_len] — elementwise when b is as
// long as a, per-channel (b[n, c] over each H×W plane) with per_value = H×W, and a
// trailing broadcast (b repeated over the leading axes) with per_value = 1; b_offset
// picks a part of b (some rows of a table).

#import gpu/for_each.wgsl

#bind p: uniform AddParams
#bind a, b: read array<Elem>
#bind y: read_write array<Elem>

fn count() -> u32 { return p.len; }

fn each(i: u32) {
    y[i] = Elem(f32(a[i]) + f32(b[p.b_offset + (i / p.per_value) % p.b_len]));
}
