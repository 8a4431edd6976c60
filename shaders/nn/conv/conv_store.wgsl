// The epilogue of the register-tiled 3×3 convolutions: reads `p: Conv2dParams` and the
// bindings `extra`, `residual` and `y` (arrays of Elem, NCHW).

// Output element `at` (image n, channel co) after the sums: plus its addend when there
// is one, rounded to Elem, plus its residual when there is one (so it equals a separate
// add.wgsl exactly).
fn finish(at: u32, n: u32, co: u32, v: f32) -> Elem {
    var out = v;
    if p.has_extra != 0u {
        out += f32(extra[n * p.c_out + co]);
    }
    if p.has_residual != 0u {
        return Elem(f32(residual[at]) + f32(Elem(out)));
    }
    return Elem(out);
}

// Output pixel `ox` of row `oy`: channels 8·block … 8·block + 7 (those below c_out).
fn store(n: u32, block: u32, oy: u32, ox: u32, lo: vec4<f32>, hi: vec4<f32>) {
    if ox >= p.w_out {
        return;
    }
    let plane = p.h_out * p.w_out;
    let out = (n * p.c_out + 8u * block) * plane + oy * p.w_out + ox;
    for (var c = 0u; c < 4u; c++) {
        let co = 8u * block + c;
        if co < p.c_out {
            y[out + c * plane] = finish(out + c * plane, n, co, lo[c]);
        }
        if co + 4u < p.c_out {
            y[out + (4u + c) * plane] = finish(out + (4u + c) * plane, n, co + 4u, hi[c]);
        }
    }
}
