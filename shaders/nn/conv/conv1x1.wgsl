// 1×1 convolution, stride 1 (NCHW, Elem storage, f32 sums) in register tiles of 8
// neighbouring pixels of a plane × 8 output channels: the pixels of a channel are
// contiguous, so each input channel costs two vec4 loads of x and two of the weights
// (repacked at load as f32 [c_in, c_out rounded up to 8], nn::ops::PackedConv) for 64
// multiply-adds. Planes of a multiple of 4 pixels (host-checked). Each output sums the
// same terms in the same order (bias, then c_in) as conv2d.wgsl. Optional bias [c_out].

#import nn/conv/conv_bias.wgsl
#import nn/conv/conv1x1_tile.wgsl

#bind p: uniform Conv2dParams
#bind x: read array<vec4<Elem>>
#bind weight: read array<vec4<f32>>
#bind bias: read array<Elem>
#bind y: read_write array<vec4<Elem>>

fn x_quad(i: u32) -> vec4<f32> {
    return vec4<f32>(x[i]);
}

fn weight_quad(i: u32) -> vec4<f32> {
    return weight[i];
}

// The tile: snippets/conv1x1_tile.wgsl.
