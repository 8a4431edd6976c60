// Picks the bin holding the wanted rank from a select histogram and clears it for the
// next frame. Pass 0: select[0] = the high-bits bin, select[1] = the rank left inside it.
// Pass 1: the median's bits, as f32, in frame[3]. One thread.

@group(0) @binding(0) var<uniform> p: SplatParams;
@group(0) @binding(1) var<storage, read_write> histogram: array<u32>;
@group(0) @binding(2) var<storage, read_write> select: array<u32>;
@group(0) @binding(3) var<storage, read_write> frame: array<f32>;

@compute @workgroup_size(1)
fn main() {
    var rank = p.mid;
    if p.round == 1u {
        rank = select[1];
    }
    var bin = 0u;
    var found = false;
    for (var b = 0u; b < 65536u; b++) {
        let count = histogram[b];
        histogram[b] = 0u;
        if !found {
            if rank < count {
                bin = b;
                found = true;
            } else {
                rank -= count;
            }
        }
    }
    if p.round == 0u {
        select[0] = bin;
        select[1] = rank;
    } else {
        frame[3] = bitcast<f32>((select[0] << 16u) | bin);
    }
}
