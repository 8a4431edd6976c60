// The window's maps as the model sees them: every foreground point of each frame turned
// `heading.to_model` quarter turns about the vertical through the centre
// (`quarter_turn`), background 0 (the engine then encodes them into the context latents).

#import gpu/for_each.wgsl

#import engine/quarter_turn.wgsl

#bind p: uniform PostParams
#bind maps: read array<Elem>
#bind point_of: read array<u32>
#bind heading: read HeadingTurns
#bind out: read_write array<Elem>

fn count() -> u32 { return p.frames * (3u * p.plane); }

fn each(i: u32) {
    let per_frame = 3u * p.plane;
    let pixel = i % p.plane;
    var v = 0.0;
    if point_of[pixel] != BACKGROUND {
        let at = (i / per_frame) * per_frame + pixel;
        let point = vec3<f32>(f32(maps[at]), f32(maps[at + p.plane]), f32(maps[at + 2u * p.plane]));
        v = quarter_turn(point, heading.to_model)[(i / p.plane) % 3u];
    }
    out[i] = Elem(v);
}
