// Each tile's run [start, end) in the sorted entries (ranges cleared to 0 beforehand).

#import gpu/for_each.wgsl

#bind keys, info: read array<u32>
#bind ranges: read_write array<vec2<u32>>

fn count() -> u32 { return info[0]; }

fn each(i: u32) {
    let count = info[0];
    let tile = keys[i] >> 16u;
    if i == 0u || (keys[i - 1u] >> 16u) != tile {
        ranges[tile].x = i;
    }
    if i == count - 1u || (keys[i + 1u] >> 16u) != tile {
        ranges[tile].y = i + 1u;
    }
}
