// y = x + table[ids[sample], channel] over NCHW images, `frames` consecutive images per
// sample: the UNet's cross-attention to its one action token, whose softmax over a
// single key is exactly 1, so its output is a per-action vector (UNet::load tabulates
// it with the same kernels; the sums here are the same additions as the layer's).

#import gpu/for_each.wgsl

#bind p: uniform ActionBiasParams
#bind x, table: read array<Elem>
#bind ids: read array<u32>
#bind y: read_write array<Elem>

fn count() -> u32 { return p.len; }

fn each(i: u32) {
    let channel = (i / p.hw) % p.channels;
    let sample = i / (p.hw * p.channels * p.frames);
    y[i] = Elem(f32(x[i]) + f32(table[ids[sample] * p.channels + channel]));
}
