// conv1x1.wgsl for CPU drivers: the same tiles (8 neighbouring pixels × 8 output
// channels) and the same sums in the same order, with the input and the packed weights
// read as texels (src/gpu/texels.rs: a vector gather on lavapipe, where a storage load
// is a loop over lanes): 4 texels per input channel for 64 multiply-adds. Planes of a
// multiple of 4 pixels (host-checked). Optional bias [c_out].

#import nn/conv/conv_bias.wgsl
#import nn/conv/conv1x1_tile.wgsl

#bind p: uniform Conv2dParams
#bind x, weight: texture_2d<f32>
#bind bias: read array<Elem>
#bind y: read_write array<vec4<Elem>>

fn x_quad(i: u32) -> vec4<f32> {
    return texel(x, i);
}

fn weight_quad(i: u32) -> vec4<f32> {
    return texel(weight, i);
}

// The tile: snippets/conv1x1_tile.wgsl.
