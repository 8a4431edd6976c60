// 1×1 convolution, stride 1 (NCHW, Elem storage, f32 sums) in register tiles of 8
// neighbouring pixels of a plane × 8 output channels: the pixels of a channel are
// contiguous, so each input channel costs two vec4 loads of x and two of the weights
// (repacked at load as f32 [c_in, c_out rounded up to 8], nn::ops::PackedConv) for 64
// multiply-adds. Planes of a multiple of 4 pixels (host-checked). Each output sums the
// same terms in the same order (bias, then c_in) as conv2d.wgsl. Optional bias [c_out].

#import nn/conv/conv_bias.wgsl
#import nn/conv/conv1x1_tile.wgsl

@group(0) @binding(0) var<uniform> p: Conv2dParams;
@group(0) @binding(1) var<storage, read> x: array<vec4<Elem>>;
@group(0) @binding(2) var<storage, read> weight: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read> bias: array<Elem>;
@group(0) @binding(4) var<storage, read_write> y: array<vec4<Elem>>;

fn x_quad(i: u32) -> vec4<f32> {
    return vec4<f32>(x[i]);
}

fn weight_quad(i: u32) -> vec4<f32> {
    return weight[i];
}

// The tile: snippets/conv1x1_tile.wgsl.
