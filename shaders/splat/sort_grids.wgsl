// What the sort's size depends on, from the entries kept (info[0]): the indirect
// dispatch grids (at 0, one workgroup per block of 256 entries for the radix histogram
// and scatter; at 12, one invocation per entry for the tile ranges; each x, y, 1 with x
// at most f.max_groups, as gpu::kernel::Grid splits it, so group_index() counts the same
// blocks), and the length of the histogram's scan (256 digits × those blocks; its
// `blocks`, the capacity's, were written when the buffers were made).

#import splat/radix_blocks.wgsl

#bind f: uniform RasterView
#bind info: read array<u32>
#bind grids: read_write array<u32>
#bind hist_scan: read_write ScanParams

fn grid(workgroups: u32, at: u32) {
    var x = workgroups;
    var y = 1u;
    if workgroups > f.max_groups {
        y = (workgroups + f.max_groups - 1u) / f.max_groups;
        x = (workgroups + y - 1u) / y;
    }
    grids[at] = x;
    grids[at + 1u] = y;
    grids[at + 2u] = 1u;
}

@compute @workgroup_size(1)
fn main(invocation: Invocation) {
    let blocks = radix_blocks();
    grid(blocks, 0u);
    hist_scan.len = 256u * blocks;
    grid((info[0] + WORKGROUP - 1u) / WORKGROUP, 3u);
}
