// The window's slide after a generated frame: frames 1.. of the context then the new
// latent, all moved by -shift in latent space (-Σ_k shift_k J_k, J untiled [3, latent]).
// Thread 0 also moves the world root by shift / scale and counts the frame.

@group(0) @binding(0) var<uniform> p: PostParams;
@group(0) @binding(1) var<storage, read> context: array<Elem>;
@group(0) @binding(2) var<storage, read> latent: array<Elem>;
@group(0) @binding(3) var<storage, read> jacobian: array<f32>;
@group(0) @binding(4) var<storage, read_write> state: FrameState;
@group(0) @binding(5) var<storage, read_write> window: array<Elem>;

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    let i = linear_index(invocation);
    if i >= p.frames * p.latent {
        return;
    }
    let frame = i / p.latent;
    let j = i % p.latent;
    var v: f32;
    if frame + 1u < p.frames {
        v = f32(context[i + p.latent]);
    } else {
        v = f32(latent[j]);
    }
    let shift = state.shift;
    for (var k = 0u; k < 3u; k++) {
        v = v + (-shift[k]) * jacobian[k * p.latent + j];
    }
    window[i] = Elem(v);
    if i == 0u {
        state.root = vec4<f32>(state.root.xyz + shift.xyz / p.scale, 0.0);
        state.frames += 1u;
    }
}
