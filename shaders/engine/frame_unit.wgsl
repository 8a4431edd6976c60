// A decoded map's foreground pixels as normalised points: NaN becomes the cube's centre
// and the rest is clamped into [0, 1] (both counted); the root shift is the mean of the
// waist points minus 0.5. The root motion is the same shift, or with a decoded reference
// (`p.decoded_reference`) the root minus the root of `reference` (the last context latent
// decoded, kept the same way). The model's frame is turned back to the world's
// (`heading.to_world` quarter turns, `quarter_turn`): the points, the root and the
// reference's root. Grounded (`p.grounded`), the motion's height is the one that puts the
// frame's lowest kept point on the floor (world y = 0): the world root after the frame is
// (root - lowest) / scale above it. The stand latch (`p.stand` > 0): under Idle
// (`heading.idle`), once the motion's horizontal part is shorter than `p.stand`, it is 0
// (the world root holds) until a frame under a movement key. One workgroup; every thread
// clamps a strided share of the points.

#import engine/quarter_turn.wgsl

#bind p: uniform PostParams
#bind map: read array<Elem>
#bind pixels, waist: read array<u32>
#bind unit: read_write array<f32>
#bind state: read_write FrameState
#bind reference: read array<Elem>
#bind heading: read HeadingTurns

var<workgroup> clamped: atomic<u32>;
// The lowest kept height, as the bits of a non-negative f32 (ordered as the values are).
var<workgroup> lowest: atomic<u32>;

// NaN from its bits: compilers may assume `x != x` is false.
fn is_nan(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7fffffffu) > 0x7f800000u;
}

fn kept(x: f32) -> f32 {
    if is_nan(x) {
        return 0.5;
    }
    return clamp(x, 0.0, 1.0);
}

fn value(point: u32, axis: u32) -> f32 {
    return f32(map[axis * p.plane + pixels[point]]);
}

// The mean of the kept waist points of `map` (from_map) or of `reference`, turned to the
// world's frame.
fn waist_root(from_map: bool) -> vec3<f32> {
    var root = vec3<f32>(0.0);
    for (var w = 0u; w < p.waist; w++) {
        let q = pixels[waist[w]];
        for (var k = 0u; k < 3u; k++) {
            var x = 0.0;
            if from_map {
                x = f32(map[k * p.plane + q]);
            } else {
                x = f32(reference[k * p.plane + q]);
            }
            root[k] += kept(x);
        }
    }
    return quarter_turn(root / f32(p.waist), heading.to_world);
}

@compute @workgroup_size(256)
fn main(@builtin(local_invocation_index) lane: u32) {
    if lane == 0u {
        atomicStore(&clamped, 0u);
        atomicStore(&lowest, bitcast<u32>(1.0));
    }
    workgroupBarrier();
    var count = 0u;
    var low = 1.0;
    for (var point = lane; point < p.points; point += 256u) {
        var v = vec3<f32>(0.0);
        for (var k = 0u; k < 3u; k++) {
            let x = value(point, k);
            if is_nan(x) || x < 0.0 || x > 1.0 {
                count += 1u;
            }
            v[k] = kept(x);
        }
        v = quarter_turn(v, heading.to_world);
        for (var k = 0u; k < 3u; k++) {
            unit[3u * point + k] = v[k];
        }
        low = min(low, v.y);
    }
    atomicAdd(&clamped, count);
    // (-0 as +0: its bits would order above every positive value)
    atomicMin(&lowest, bitcast<u32>(select(low, 0.0, low <= 0.0)));
    workgroupBarrier();
    if lane == 0u {
        let root = waist_root(true);
        state.shift = vec4<f32>(root - vec3<f32>(0.5), 0.0);
        var origin = vec3<f32>(0.5);
        if p.decoded_reference != 0u {
            origin = waist_root(false);
        }
        var motion = root - origin;
        if p.grounded != 0u {
            motion.y = root.y - bitcast<f32>(atomicLoad(&lowest)) - p.scale * state.root.y;
        }
        if p.stand > 0.0 {
            if heading.idle == 0u {
                state.standing = 0u;
            } else if state.standing != 0u || length(motion.xz) < p.stand {
                state.standing = 1u;
                motion.x = 0.0;
                motion.z = 0.0;
            }
        }
        state.motion = vec4<f32>(motion, 0.0);
        let n = atomicLoad(&clamped);
        state.clamped = n;
        state.clamped_total += n;
    }
}
