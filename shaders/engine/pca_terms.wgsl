// The bindings of the PCA coefficient kernels and the sum they share: c_k = Σ_d
// basis[k, d] · (unit[d] - shift[d % 3] - mean[d]) over the frame's texels (the frame
// centred on its own root: docs/architecture.md, The live loop). The frame, the mean
// and the basis are read as texels (src/gpu/texels.rs), four values a fetch; each basis
// row is padded with zeros to whole texels, so the padding adds exact zeros.

#bind p: uniform PostParams
#bind unit, mean, basis: texture_2d<f32>
#bind state: read FrameState
#bind coefficients: read_write array<f32>

// Texels of one frame (and of one basis row).
fn frame_texels() -> u32 {
    return (3u * p.points + 3u) / 4u;
}

// Component k's terms over texels first, first + step, … below `end`, summed in order.
fn pca_terms(k: u32, first: u32, step: u32, end: u32) -> f32 {
    let row = k * frame_texels();
    // Value 4j + c is on axis (j + c) % 3 (4 ≡ 1 mod 3): the shifts of texel j by j % 3.
    let s = state.shift;
    let s0 = vec4<f32>(s[0], s[1], s[2], s[0]);
    let s1 = vec4<f32>(s[1], s[2], s[0], s[1]);
    let s2 = vec4<f32>(s[2], s[0], s[1], s[2]);
    var c = 0.0;
    for (var j = first; j < end; j += step) {
        let phase = j % 3u;
        let shift = select(select(s0, s1, phase == 1u), s2, phase == 2u);
        let b = texel(basis, row + j);
        let v = texel(unit, j) - shift - texel(mean, j);
        c += b.x * v.x;
        c += b.y * v.y;
        c += b.z * v.z;
        c += b.w * v.w;
    }
    return c;
}
