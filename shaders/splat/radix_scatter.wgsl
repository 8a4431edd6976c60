// Radix sort, pass part 2: each key goes to its (digit, block) offset plus its rank among
// the earlier keys of its block with the same digit — a stable pass, so passes from the
// lowest digit up sort by the whole key, equal keys keeping their order.

#import splat/radix_blocks.wgsl

#bind p: uniform RadixParams
#bind keys, values, info, hist: read array<u32>
#bind keys_out, values_out: read_write array<u32>

var<workgroup> digits: array<u32, 256>;

@compute @workgroup_size(256)
fn main(invocation: Invocation) {
    let block = group_index(invocation);
    let lane = invocation.lane;
    let i = block * 256u + lane;
    let inside = i < info[0];
    var digit = 256u;
    if inside {
        digit = (keys[i] >> p.shift) & 255u;
    }
    digits[lane] = digit;
    workgroupBarrier();
    if !inside {
        return;
    }
    var rank = 0u;
    for (var j = 0u; j < lane; j++) {
        if digits[j] == digit {
            rank++;
        }
    }
    let at = hist[digit * radix_blocks() + block] + rank;
    keys_out[at] = keys[i];
    values_out[at] = values[i];
}
