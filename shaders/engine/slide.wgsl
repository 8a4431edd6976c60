// The window's slide after a generated frame, as position maps: frames 1 and 2 of the
// window's maps then the new frame's clamped points, every foreground value moved by
// -shift, background 0 (the engine encodes the result into the next context latents).
// Thread 0 also moves the world root by the root motion / scale and counts the frame.

#import gpu/for_each.wgsl

#bind p: uniform PostParams
#bind maps: read array<Elem>
#bind unit: read array<f32>
#bind point_of: read array<u32>
#bind state: read_write FrameState
#bind next: read_write array<Elem>

fn count() -> u32 { return p.frames * (3u * p.plane); }

fn each(i: u32) {
    let per_frame = 3u * p.plane;
    let shift = state.shift;
    let frame = i / per_frame;
    let axis = (i / p.plane) % 3u;
    let point = point_of[i % p.plane];
    var v = 0.0;
    if point != BACKGROUND {
        if frame + 1u < p.frames {
            v = f32(maps[i + per_frame]);
        } else {
            v = unit[3u * point + axis];
        }
        v -= shift[axis];
    }
    next[i] = Elem(v);
    if i == 0u {
        state.root = vec4<f32>(state.root.xyz + state.motion.xyz / p.scale, 0.0);
        state.frames += 1u;
    }
}
