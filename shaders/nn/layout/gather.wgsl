// Rows by index (Elem storage): y[i, :] = x[index[i], :] — sorting points into a curve's
// order, back again, and copying a pooled group's features to its points.

#import gpu/for_each.wgsl

@group(0) @binding(0) var<uniform> p: GatherParams;
@group(0) @binding(1) var<storage, read> index: array<u32>;
@group(0) @binding(2) var<storage, read> x: array<Elem>;
@group(0) @binding(3) var<storage, read_write> y: array<Elem>;

fn count() -> u32 { return p.rows * p.width; }

fn each(i: u32) {
    let row = i / p.width;
    y[i] = x[index[row] * p.width + i % p.width];
}
