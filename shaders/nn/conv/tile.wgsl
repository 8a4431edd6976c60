// The output tiles of the row-tiled convolutions: `width` neighbouring output pixels of
// a row × 8 output channels (a channel block), numbered pixel tile fastest, then row,
// channel block, image. Reads `p: Conv2dParams`.
struct Tile {
    n: u32,
    block: u32,
    oy: u32,
    // The tile's first output column.
    ox0: u32,
}

// Blocks of 8 output channels (the last one partial when c_out is not a multiple of 8).
fn channel_blocks() -> u32 {
    return (p.c_out + 7u) / 8u;
}

// Tiles of `width` pixels along an output row.
fn row_tiles(width: u32) -> u32 {
    return (p.w_out + width - 1u) / width;
}

// How many tiles of `width` pixels the output has.
fn tile_count(width: u32) -> u32 {
    return p.batch * channel_blocks() * p.h_out * row_tiles(width);
}

// Tile i of `width` pixels.
fn tile_at(i: u32, width: u32) -> Tile {
    let blocks = channel_blocks();
    let tiles = row_tiles(width);
    let n = i / (tiles * p.h_out * blocks);
    let block = (i / (tiles * p.h_out)) % blocks;
    return Tile(n, block, (i / tiles) % p.h_out, (i % tiles) * width);
}
