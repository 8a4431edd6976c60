// The output tiles of the register-tiled linear layers: `size` outputs × `size` rows,
// numbered output tile fastest. Reads `p: LinearParams`.

// How many tiles of `size` × `size` the output has.
fn linear_tile_count(size: u32) -> u32 {
    return ((p.outputs + size - 1u) / size) * ((p.rows + size - 1u) / size);
}

// Tile i's first output (x) and first row (y).
fn linear_tile_at(i: u32, size: u32) -> vec2<u32> {
    let out_tiles = (p.outputs + size - 1u) / size;
    return vec2<u32>(i % out_tiles, i / out_tiles) * size;
}
