// (mean, 1 / std) of `count` values (a multiple of 4) held as texels of `t` from texel
// `first`: four running partial sums, two passes (the mean, then the squared deviations).
// Every CPU-driver norm takes its statistics from here (group_norm_serial.wgsl, the
// layer norm in linear_cpu.wgsl's loads, the folded norm in conv3x3_cpu.wgsl), so the
// fused forms give the separate norm's bits.
fn texel_stats(t: texture_2d<f32>, first: u32, count: u32, eps: f32) -> vec2<f32> {
    let quads = count / 4u;
    var sum = vec4<f32>(0.0);
    for (var i = 0u; i < quads; i++) {
        sum += texel(t, first + i);
    }
    let mean = (sum.x + sum.y + sum.z + sum.w) / f32(count);
    var squares = vec4<f32>(0.0);
    for (var i = 0u; i < quads; i++) {
        let d = texel(t, first + i) - mean;
        squares += d * d;
    }
    return vec2<f32>(mean, inverseSqrt((squares.x + squares.y + squares.z + squares.w) / f32(count) + eps));
}
