// Radix sort, between the two parts of a pass, for CPU drivers: the exclusive prefix sum
// of the digit counts in their digit-major order (hist[digit · blocks + block]), in
// place, by one workgroup: lane d sums digit d's counts over the blocks, the 256 totals
// meet in shared memory behind one barrier, and each lane writes its digit's offsets.
// The same offsets as the generic scan (scan_blocks.wgsl and scan_add.wgsl, GPUs), whose
// barrier-stepped levels took about 8 ms a pass at 640 × 400 on lavapipe.

#import splat/radix_blocks.wgsl

#bind info: read array<u32>
#bind hist: read_write array<u32>

var<workgroup> totals: array<u32, 256>;

@compute @workgroup_size(256)
fn main(invocation: Invocation) {
    let digit = invocation.lane;
    let blocks = radix_blocks();
    var total = 0u;
    for (var b = 0u; b < blocks; b++) {
        total += hist[digit * blocks + b];
    }
    totals[digit] = total;
    workgroupBarrier();
    var sum = 0u;
    for (var d = 0u; d < digit; d++) {
        sum += totals[d];
    }
    for (var b = 0u; b < blocks; b++) {
        let at = digit * blocks + b;
        let count = hist[at];
        hist[at] = sum;
        sum += count;
    }
}
