// Strided pooling (Elem storage, f32 sums): y[g, :] is the mean of rows g·stride ..
// min((g + 1)·stride, rows) of x, summed in row order (the last group may be shorter).

#import gpu/for_each.wgsl

#bind p: uniform SegmentParams
#bind x: read array<Elem>
#bind y: read_write array<Elem>

fn count() -> u32 { return ((p.rows + p.stride - 1u) / p.stride) * p.width; }

fn each(i: u32) {
    let g = i / p.width;
    let c = i % p.width;
    let end = min((g + 1u) * p.stride, p.rows);
    var total = 0.0;
    for (var r = g * p.stride; r < end; r++) {
        total += f32(x[r * p.width + c]);
    }
    y[i] = Elem(total / f32(end - g * p.stride));
}
