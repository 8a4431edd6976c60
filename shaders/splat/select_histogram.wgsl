// Exact selection of the `mid`-th smallest distance (distances are ≥ 0, so their bits
// order as u32): pass 0 counts the high 16 bits of every distance, pass 1 the low 16
// bits of those whose high bits are the bin pass 0 picked (select[0]).

#import gpu/for_each.wgsl

#bind p: uniform SplatParams
#bind distances: read array<f32>
#bind select: read array<u32>
#bind histogram: read_write array<atomic<u32>>

fn count() -> u32 { return p.pairs; }

fn each(m: u32) {
    let bits = bitcast<u32>(distances[m]);
    if p.round == 0u {
        atomicAdd(&histogram[bits >> 16u], 1u);
    } else if (bits >> 16u) == select[0] {
        atomicAdd(&histogram[bits & 0xffffu], 1u);
    }
}
