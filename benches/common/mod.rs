//! What the kernel probes (`loads`, `stores`) share: build a WGSL kernel, bind its
//! resources and time its dispatches on the present adapter.

use std::time::Instant;

use unica::gpu::GpuContext;

/// Milliseconds one dispatch of `wgsl`'s `main` over `groups` workgroups (x, y) takes
/// with `resources` at bindings 0, 1, … of group 0: `repeats` dispatches in one
/// submission, waited for, after one alone as a warm-up.
pub fn time_dispatch(
    gpu: &GpuContext,
    wgsl: &str,
    resources: Vec<wgpu::BindingResource>,
    groups: (u32, u32),
    repeats: usize,
) -> f64 {
    let device = &gpu.device;
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("probe"),
        source: wgpu::ShaderSource::Wgsl(wgsl.into()),
    });
    let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some("probe"),
        layout: None,
        module: &module,
        entry_point: Some("main"),
        compilation_options: Default::default(),
        cache: None,
    });
    let entries: Vec<wgpu::BindGroupEntry> = resources
        .into_iter()
        .enumerate()
        .map(|(i, resource)| wgpu::BindGroupEntry {
            binding: i as u32,
            resource,
        })
        .collect();
    let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("probe"),
        layout: &pipeline.get_bind_group_layout(0),
        entries: &entries,
    });
    let run = |repeats: usize| {
        let mut encoder = device.create_command_encoder(&Default::default());
        {
            let mut pass = encoder.begin_compute_pass(&Default::default());
            pass.set_pipeline(&pipeline);
            pass.set_bind_group(0, &bind_group, &[]);
            for _ in 0..repeats {
                pass.dispatch_workgroups(groups.0, groups.1, 1);
            }
        }
        gpu.queue.submit([encoder.finish()]);
        gpu.wait_idle();
    };
    run(1);
    let clock = Instant::now();
    run(repeats);
    clock.elapsed().as_secs_f64() * 1e3 / repeats as f64
}
