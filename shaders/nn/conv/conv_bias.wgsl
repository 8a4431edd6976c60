// The bias of output channels 8·block … 8·block + 7 (the last one repeated past c_out),
// or zeros without a bias: the starting sums of a convolution's tile of 8 channels.
// Reads `p: Conv2dParams` and `bias: array<Elem>`.
struct Lanes {
    lo: vec4<f32>,
    hi: vec4<f32>,
}

fn bias_lanes(block: u32) -> Lanes {
    var out = Lanes(vec4<f32>(0.0), vec4<f32>(0.0));
    if p.has_bias != 0u {
        let last = p.c_out - 1u;
        let co = min(vec4<u32>(8u * block) + vec4<u32>(0u, 1u, 2u, 3u), vec4<u32>(last));
        let co2 = min(co + vec4<u32>(4u), vec4<u32>(last));
        out.lo = vec4<f32>(f32(bias[co.x]), f32(bias[co.y]), f32(bias[co.z]), f32(bias[co.w]));
        out.hi = vec4<f32>(f32(bias[co2.x]), f32(bias[co2.y]), f32(bias[co2.z]), f32(bias[co2.w]));
    }
    return out;
}
