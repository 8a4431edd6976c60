// Picks the bin holding the wanted rank from a select histogram and clears it for the
// next frame. Pass 0: select[0] = the high-bits bin, select[1] = the rank left inside it.
// Pass 1: the median's bits, as f32, in frame[3].
//
// One workgroup of 256 threads; the 65,536 bins are 256 chunks of 256. Each thread sums
// one chunk, every thread then finds from the chunk sums whether the rank falls in its
// chunk, the 256 bins of that chunk are read into shared memory, and the same search
// inside it names the bin. One thread walking all 65,536 bins took 12.5 ms a pass on an
// NVIDIA H200 (docs/gpu); this takes a few microseconds, and is cheap on lavapipe too
// (four barriers).

#bind p: uniform SplatParams
#bind histogram, select: read_write array<u32>
#bind frame: read_write array<f32>

const CHUNK: u32 = 256u;

var<workgroup> counts: array<u32, 256>;
// The chunk (then bin) that holds the rank and the rank left inside it; CHUNK when none
// does (a rank past the total, which the callers never ask for).
var<workgroup> found: u32;
var<workgroup> left: u32;

// Whether `rank` falls in entry t of `counts` (the entries before t are skipped): then
// `left` is the rank inside it. Every thread sums the entries before its own.
fn search(t: u32, rank: u32) {
    var before = 0u;
    for (var i = 0u; i < t; i++) {
        before += counts[i];
    }
    if rank >= before && rank - before < counts[t] {
        found = t;
        left = rank - before;
    }
}

@compute @workgroup_size(256)
fn main(@builtin(local_invocation_index) t: u32) {
    var rank = p.mid;
    if p.round == 1u {
        rank = select[1];
    }
    if t == 0u {
        found = CHUNK;
    }
    var sum = 0u;
    for (var i = 0u; i < CHUNK; i++) {
        sum += histogram[t * CHUNK + i];
    }
    counts[t] = sum;
    workgroupBarrier();
    search(t, rank);
    // workgroupUniformLoad waits for every thread's search: the branch below is uniform.
    let chunk = workgroupUniformLoad(&found);
    var bin = 0u;
    if chunk < CHUNK {
        let inside = left;
        workgroupBarrier();
        counts[t] = histogram[chunk * CHUNK + t];
        workgroupBarrier();
        search(t, inside);
        bin = chunk * CHUNK + workgroupUniformLoad(&found);
        rank = left;
    } else {
        // Not found: as a walk over every bin would end, bin 0 and the rank past all.
        var total = 0u;
        for (var i = 0u; i < CHUNK; i++) {
            total += counts[i];
        }
        rank -= total;
    }
    // Every read of the histogram is done: clear this thread's chunk.
    storageBarrier();
    for (var i = 0u; i < CHUNK; i++) {
        histogram[t * CHUNK + i] = 0u;
    }
    if t == 0u {
        if p.round == 0u {
            select[0] = bin;
            select[1] = rank;
        } else {
            frame[3] = bitcast<f32>((select[0] << 16u) | bin);
        }
    }
}
