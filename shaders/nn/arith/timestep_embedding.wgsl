// Sinusoidal timestep embedding: for each timestep t and k < half, out[k] = cos(t f_k) and
// out[half + k] = sin(t f_k) with f_k = exp(-ln(10000) k / half) — the trainer's order.

#import gpu/for_each.wgsl

#bind p: uniform EmbeddingParams
#bind t: read array<Elem>
#bind y: read_write array<Elem>

fn count() -> u32 { return p.count * (p.dim / 2u); }

fn each(i: u32) {
    let half = p.dim / 2u;
    let k = i % half;
    let row = i / half;
    let freq = exp(-log(10000.0) * f32(k) / f32(half));
    let arg = f32(t[row]) * freq;
    y[row * p.dim + k] = Elem(cos(arg));
    y[row * p.dim + half + k] = Elem(sin(arg));
}
