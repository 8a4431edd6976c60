// Serialisation codes (PTv3, as src/splat/serialise.rs): each point's unit-cube position
// quantised to 1024 cells per axis, as a z-order and a Hilbert index, and both with x and
// y swapped: codes[curve · stride + i], curves in the refiner's order (Z, Z transposed,
// Hilbert, Hilbert transposed). 30 bits each.

#bind p: uniform SplatParams
#bind unit: read array<f32>
#bind codes: read_write array<u32>

fn quantise(v: f32) -> u32 {
    return u32(clamp(floor(v * 1024.0), 0.0, 1023.0));
}

fn interleave(c: vec3<u32>) -> u32 {
    var code = 0u;
    for (var b = 9i; b >= 0i; b--) {
        code = (code << 1u) | ((c.x >> u32(b)) & 1u);
        code = (code << 1u) | ((c.y >> u32(b)) & 1u);
        code = (code << 1u) | ((c.z >> u32(b)) & 1u);
    }
    return code;
}

fn hilbert(cell: vec3<u32>) -> u32 {
    var x = array<u32, 3>(cell.x, cell.y, cell.z);
    var q = 1u << 9u;
    while q > 1u {
        let m = q - 1u;
        for (var i = 0u; i < 3u; i++) {
            if (x[i] & q) != 0u {
                x[0] ^= m;
            } else {
                let t = (x[0] ^ x[i]) & m;
                x[0] ^= t;
                x[i] ^= t;
            }
        }
        q >>= 1u;
    }
    x[1] ^= x[0];
    x[2] ^= x[1];
    var t = 0u;
    q = 1u << 9u;
    while q > 1u {
        if (x[2] & q) != 0u {
            t ^= q - 1u;
        }
        q >>= 1u;
    }
    return interleave(vec3<u32>(x[0] ^ t, x[1] ^ t, x[2] ^ t));
}

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    let i = linear_index(invocation);
    // Each curve's codes fill `stride` slots (points rounded up to 4, so rank_tiled.wgsl reads
    // them as vec4s); the padding holds the largest u32, after every 30-bit code.
    let stride = (p.points + 3u) / 4u * 4u;
    if i >= stride {
        return;
    }
    if i >= p.points {
        for (var curve = 0u; curve < 4u; curve++) {
            codes[curve * stride + i] = 0xffffffffu;
        }
        return;
    }
    let c = vec3<u32>(quantise(unit[3u * i]), quantise(unit[3u * i + 1u]), quantise(unit[3u * i + 2u]));
    let t = vec3<u32>(c.y, c.x, c.z);
    codes[i] = interleave(c);
    codes[stride + i] = interleave(t);
    codes[2u * stride + i] = hilbert(c);
    codes[3u * stride + i] = hilbert(t);
}
