// Values s … s + 3 of the eight values (a, b), for s in 0 … 3: a run of values read as
// texels that starts anywhere in a texel (the CPU-driver convolutions' rows).
fn pick(a: vec4<f32>, b: vec4<f32>, s: u32) -> vec4<f32> {
    let s1 = vec4<f32>(a.y, a.z, a.w, b.x);
    let s2 = vec4<f32>(a.z, a.w, b.x, b.y);
    let s3 = vec4<f32>(a.w, b.x, b.y, b.z);
    return select(select(select(a, s1, s == 1u), s2, s == 2u), s3, s == 3u);
}
