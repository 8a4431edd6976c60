// Rows by index (Elem storage): y[i, :] = x[index[i], :] — sorting points into a curve's
// order, back again, and copying a pooled group's features to its points.

#import gpu/for_each.wgsl

#bind p: uniform GatherParams
#bind index: read array<u32>
#bind x: read array<Elem>
#bind y: read_write array<Elem>

fn count() -> u32 { return p.rows * p.width; }

fn each(i: u32) {
    let row = i / p.width;
    y[i] = x[index[row] * p.width + i % p.width];
}
