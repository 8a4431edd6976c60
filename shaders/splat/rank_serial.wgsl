// The serialisation ranks for CPU drivers: the same ranks, orders and groups as
// rank_tiled.wgsl (a point's rank is the number of points with a smaller code plus those
// with the same code and a smaller index), by a stable least-significant-digit radix sort
// that one invocation runs serially: three passes of 10 bits over the 30-bit codes, each
// counting its digits in a private array, then placing the points in their order. `unsort`
// is the middle pass's buffer before it gets the inverse order. Counting every pair took
// 4,414² compares, about 11 ms a curve of 4,414 points on lavapipe. Lavapipe's limit on
// loop iterations bounds the points it can sort: frame.rs's RANK_SERIAL_MAX_POINTS.

#bind p: uniform SplatParams
#bind codes: read array<u32>
#bind sort, unsort, groups_out: read_write array<u32>

const DIGITS: u32 = 1024u;

// The k-th point of the order that pass `round` reads: the points in index order, then
// the first pass's order (in `sort`), then the second's (in `unsort`).
fn source(round: u32, k: u32) -> u32 {
    if round == 0u {
        return k;
    }
    if round == 1u {
        return sort[k];
    }
    return unsort[k];
}

@compute @workgroup_size(1)
fn main(invocation: Invocation) {
    if group_index(invocation) != 0u {
        return;
    }
    let n = p.points;
    // Each curve's codes fill the points rounded up to 4 (codes.wgsl).
    let base = p.curve * ((n + 3u) / 4u * 4u);
    var starts: array<u32, DIGITS>;
    for (var round = 0u; round < 3u; round++) {
        let shift = 10u * round;
        for (var d = 0u; d < DIGITS; d++) {
            starts[d] = 0u;
        }
        for (var k = 0u; k < n; k++) {
            let d = (codes[base + source(round, k)] >> shift) & (DIGITS - 1u);
            starts[d] += 1u;
        }
        var total = 0u;
        for (var d = 0u; d < DIGITS; d++) {
            let c = starts[d];
            starts[d] = total;
            total += c;
        }
        for (var k = 0u; k < n; k++) {
            let i = source(round, k);
            let d = (codes[base + i] >> shift) & (DIGITS - 1u);
            let at = starts[d];
            starts[d] = at + 1u;
            if round == 1u {
                unsort[at] = i;
            } else {
                sort[at] = i;
            }
        }
    }
    for (var r = 0u; r < n; r++) {
        let i = sort[r];
        unsort[i] = r;
        if p.features != 0u {
            groups_out[i] = r / p.stride;
        }
    }
}
