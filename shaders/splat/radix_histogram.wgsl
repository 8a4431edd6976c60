// Radix sort, pass part 1: each workgroup counts the 8-bit digits (at `shift`) of its 256
// keys and writes the counts digit-major (hist[digit · blocks + block], blocks of the
// entries kept, info[0]), so one exclusive scan of the first 256 · blocks values of
// `hist` gives every (digit, block) its first output position.

#import splat/radix_blocks.wgsl

#bind p: uniform RadixParams
#bind keys, info: read array<u32>
#bind hist: read_write array<u32>

var<workgroup> counts: array<atomic<u32>, 256>;

@compute @workgroup_size(256)
fn main(invocation: Invocation) {
    let block = group_index(invocation);
    let lane = invocation.lane;
    atomicStore(&counts[lane], 0u);
    workgroupBarrier();
    let i = block * 256u + lane;
    if i < info[0] {
        atomicAdd(&counts[(keys[i] >> p.shift) & 255u], 1u);
    }
    workgroupBarrier();
    let blocks = radix_blocks();
    if block < blocks {
        hist[lane * blocks + block] = atomicLoad(&counts[lane]);
    }
}
