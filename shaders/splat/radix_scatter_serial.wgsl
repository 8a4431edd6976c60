// Radix sort, pass part 2, for CPU drivers: as radix_scatter.wgsl, but one invocation
// places its block's keys in order, counting each digit's keys placed so far in a
// private array: the same stable positions without shared memory or barriers, and 256
// steps a block instead of every key comparing itself with the keys before it.

#import splat/radix_blocks.wgsl

#bind p: uniform RadixParams
#bind keys, values, info, hist: read array<u32>
#bind keys_out, values_out: read_write array<u32>

@compute @workgroup_size(1)
fn main(invocation: Invocation) {
    let block = group_index(invocation);
    let blocks = radix_blocks();
    if block >= blocks {
        return;
    }
    var placed: array<u32, 256>;
    for (var i = block * 256u; i < radix_block_end(block); i++) {
        let key = keys[i];
        let digit = (key >> p.shift) & 255u;
        let at = hist[digit * blocks + block] + placed[digit];
        placed[digit] += 1u;
        keys_out[at] = key;
        values_out[at] = values[i];
    }
}
