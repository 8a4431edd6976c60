// A normalised point turned `turns` quarter turns about the vertical through the cube's
// centre (x = z = 0.5), the trainer's `dataset.quarter_turn`: each turn takes
// (x, y, z) to (z, y, -x) about the centre, +Z to +X.
fn quarter_turn(v: vec3<f32>, turns: u32) -> vec3<f32> {
    let x = v.x - 0.5;
    let z = v.z - 0.5;
    switch turns % 4u {
        case 1u: {
            return vec3<f32>(z + 0.5, v.y, 0.5 - x);
        }
        case 2u: {
            return vec3<f32>(0.5 - x, v.y, 0.5 - z);
        }
        case 3u: {
            return vec3<f32>(0.5 - z, v.y, x + 0.5);
        }
        default: {
            return v;
        }
    }
}
