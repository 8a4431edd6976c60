// Radix sort, pass part 1, for CPU drivers: as radix_histogram.wgsl, but one invocation
// counts its block's 256 digits in a private array, serially: no shared memory, no
// atomics and no barriers (a CPU driver runs each barrier as a switch between the
// workgroup's invocations). Same grid: one workgroup per block of 256 entries.

#import splat/radix_blocks.wgsl

#bind p: uniform RadixParams
#bind keys, info: read array<u32>
#bind hist: read_write array<u32>

@compute @workgroup_size(1)
fn main(invocation: Invocation) {
    let block = group_index(invocation);
    let blocks = radix_blocks();
    if block >= blocks {
        return;
    }
    var counts: array<u32, 256>;
    for (var i = block * 256u; i < radix_block_end(block); i++) {
        let digit = (keys[i] >> p.shift) & 255u;
        counts[digit] += 1u;
    }
    for (var digit = 0u; digit < 256u; digit++) {
        hist[digit * blocks + block] = counts[digit];
    }
}
