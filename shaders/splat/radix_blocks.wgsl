// The radix sort's blocks: 256 sort entries each, over the entries kept (info[0], from
// splat_keys.wgsl). The histogram's stride, its scan's length and the sort's grids all
// follow them. Reads `info: array<u32>`.
fn radix_blocks() -> u32 {
    return (info[0] + 255u) / 256u;
}

// The end of `block`'s entries (its last block may hold fewer than 256).
fn radix_block_end(block: u32) -> u32 {
    return min(info[0], block * 256u + 256u);
}
