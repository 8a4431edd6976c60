// gather.wgsl for CPU drivers: rows by index (Elem storage), y[i, :] = x[index[i], :],
// four values per invocation read as one texel of x (src/gpu/texels.rs: a vector
// gather on lavapipe, where a storage load is a loop over lanes). Rows of a multiple of
// 4 values (host-checked).

#import gpu/for_each.wgsl

#bind p: uniform GatherParams
#bind index: read array<u32>
#bind x: texture_2d<f32>
#bind y: read_write array<Elem>

fn count() -> u32 { return p.rows * (p.width / 4u); }

fn each(i: u32) {
    let quads = p.width / 4u;
    let v = texel(x, index[i / quads] * quads + i % quads);
    y[4u * i] = Elem(v.x);
    y[4u * i + 1u] = Elem(v.y);
    y[4u * i + 2u] = Elem(v.z);
    y[4u * i + 3u] = Elem(v.w);
}
