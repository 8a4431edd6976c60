// The entry point of a kernel with one invocation per item: `each(i)` runs once for
// every i below `count()`, both declared by the file that imports this one, on the 2-D
// grid of workgroups that gpu::kernel::Grid sizes so any count fits the device's limits.
// Dispatch it with `Grid::for_elements(count, …)`.

@compute @workgroup_size(WORKGROUP)
fn main(invocation: Invocation) {
    let i = linear_index(invocation);
    if i < count() {
        each(i);
    }
}
