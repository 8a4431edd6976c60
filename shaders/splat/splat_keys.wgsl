// One sort entry per (splat, covered tile): key = tile << 16 | 16-bit depth, value = the
// splat's index, written at the splat's scanned offset (tiles in row-major order).
// Entries past the capacity are dropped; info = [entries kept, entries wanted].

#import gpu/for_each.wgsl

#bind f: uniform RasterView
#bind projected: read array<ProjectedSplat>
#bind touched, offsets: read array<u32>
#bind keys, values, info: read_write array<u32>

fn count() -> u32 { return f.splats; }

fn each(i: u32) {
    if i == f.splats - 1u {
        let wanted = offsets[i] + touched[i];
        info[0] = min(wanted, f.capacity);
        info[1] = wanted;
    }
    if touched[i] == 0u {
        return;
    }
    let p = projected[i];
    let depth = u32(clamp(p.center_depth.z / f.depth_range, 0.0, 1.0) * 65535.0);
    var at = offsets[i];
    for (var ty = p.tiles.y; ty < p.tiles.w; ty++) {
        for (var tx = p.tiles.x; tx < p.tiles.z; tx++) {
            if at < f.capacity {
                keys[at] = ((ty * f.tiles_x + tx) << 16u) | depth;
                values[at] = i;
            }
            at++;
        }
    }
}
