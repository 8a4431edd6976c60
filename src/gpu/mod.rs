//! GPU context: adapter choice, device creation with optional features and their fallbacks.
//! Owns everything every other GPU module needs: the device, the queue and what it can do.

pub mod counters;
pub mod indices;
pub mod kernel;
pub mod plan;
pub mod precision;
pub mod readback;
pub mod shaders;
pub mod texels;
pub mod timing;

use std::fmt;
use std::sync::Arc;

pub use counters::{Counters, Counts};
pub use indices::{Indices, Permutation};

/// Environment variable that picks an adapter by (case-insensitive) substring of its name.
pub const ADAPTER_ENV: &str = "WGPU_ADAPTER_NAME";
/// Environment variable that forces the fallback path (f32 only, no subgroups, CPU timers).
pub const FALLBACK_ENV: &str = "UNICA_FORCE_FALLBACK";

/// What the caller wants from the GPU before any adapter is looked at.
#[derive(Clone, Debug, Default)]
pub struct GpuOptions {
    /// Request no optional feature even where the adapter has it (tests the fallback path).
    pub force_fallback: bool,
    /// Substring of the adapter name to use; `None` takes the best adapter.
    pub adapter_name: Option<String>,
}

impl GpuOptions {
    /// Options from `WGPU_ADAPTER_NAME` and `UNICA_FORCE_FALLBACK` (any value but `0` or empty).
    pub fn from_env() -> Self {
        let force_fallback = std::env::var(FALLBACK_ENV)
            .map(|v| !v.is_empty() && v != "0")
            .unwrap_or(false);
        let adapter_name = std::env::var(ADAPTER_ENV).ok().filter(|v| !v.is_empty());
        Self {
            force_fallback,
            adapter_name,
        }
    }
}

/// Optional capabilities in use on this device (each false on the fallback path).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Capabilities {
    /// `enable f16;` shaders may be used (f16 storage and arithmetic).
    pub shader_f16: bool,
    /// Subgroup operations may be used.
    pub subgroups: bool,
    /// GPU timestamp queries in compute and render passes.
    pub timestamps: bool,
}

impl Capabilities {
    fn features(self) -> wgpu::Features {
        let mut features = wgpu::Features::empty();
        features.set(wgpu::Features::SHADER_F16, self.shader_f16);
        features.set(wgpu::Features::SUBGROUP, self.subgroups);
        features.set(wgpu::Features::TIMESTAMP_QUERY, self.timestamps);
        features
    }

    /// The capabilities to request from an adapter under the given options.
    pub fn for_adapter(adapter: &wgpu::Adapter, options: &GpuOptions) -> Self {
        let has = adapter.features();
        let want = !options.force_fallback;
        Self {
            shader_f16: want && has.contains(wgpu::Features::SHADER_F16),
            subgroups: want && has.contains(wgpu::Features::SUBGROUP),
            timestamps: want && has.contains(wgpu::Features::TIMESTAMP_QUERY),
        }
    }
}

/// Everything that can go wrong setting up or using the GPU context.
#[derive(Debug, thiserror::Error)]
pub enum GpuError {
    #[error(
        "no GPU adapter found (backends: {backends}); install a GPU driver, or Mesa's CPU Vulkan \
         driver (Debian/Ubuntu: `apt-get install mesa-vulkan-drivers libvulkan1`)"
    )]
    NoAdapter { backends: String },
    #[error(
        "no GPU adapter name contains '{wanted}' (set by {ADAPTER_ENV}); available: {available}"
    )]
    NoMatchingAdapter { wanted: String, available: String },
    #[error("could not create a device on '{adapter}': {source}")]
    Device {
        adapter: String,
        source: wgpu::RequestDeviceError,
    },
    #[error(
        "buffer '{label}' needs {size} bytes, more than this adapter binds at once \
         ({max} bytes, max_storage_buffer_binding_size); split it"
    )]
    BufferTooLarge { label: String, size: u64, max: u64 },
    #[error("GPU readback of '{label}' failed: {reason}")]
    Readback { label: String, reason: String },
    #[error("{what} is more than this GPU path handles: {limit}")]
    TooLarge { what: String, limit: String },
    /// Work that cannot be recorded as asked (the message names what and why).
    #[error("{0}")]
    Invalid(String),
}

/// The backends to try: `WGPU_BACKEND` if set, else the native APIs (Vulkan, Metal,
/// DX12). OpenGL is only a fallback (no f16, no subgroups) and its drivers are noisy.
pub fn backends() -> wgpu::Backends {
    wgpu::Backends::from_env().unwrap_or(wgpu::Backends::PRIMARY)
}

/// All adapters on [`backends`]; without a `WGPU_BACKEND` choice, OpenGL ones are looked
/// for only when no native adapter exists.
pub async fn enumerate_adapters() -> Vec<wgpu::Adapter> {
    let adapters = instance(backends()).enumerate_adapters(backends()).await;
    if adapters.is_empty() && wgpu::Backends::from_env().is_none() {
        return instance(wgpu::Backends::GL)
            .enumerate_adapters(wgpu::Backends::GL)
            .await;
    }
    adapters
}

fn instance(backends: wgpu::Backends) -> wgpu::Instance {
    wgpu::Instance::new(wgpu::InstanceDescriptor {
        backends,
        ..wgpu::InstanceDescriptor::new_without_display_handle()
    })
}

fn adapter_label(adapter: &wgpu::Adapter) -> String {
    let info = adapter.get_info();
    format!("{} ({:?}, {:?})", info.name, info.backend, info.device_type)
}

/// Preference order for adapters when no name is given: real GPUs first, CPU drivers last.
fn rank(adapter: &wgpu::Adapter) -> u8 {
    let info = adapter.get_info();
    let device = match info.device_type {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 3,
        wgpu::DeviceType::Cpu => 4,
    };
    // Among equals prefer the native APIs over GL (no f16, no subgroups there).
    let backend = u8::from(info.backend == wgpu::Backend::Gl);
    device * 2 + backend
}

/// Picks the adapter: by name if asked for one, else the best ranked; `surface` filters
/// out adapters that cannot present to the window.
pub fn select_adapter(
    adapters: &[wgpu::Adapter],
    surface: Option<&wgpu::Surface<'_>>,
    options: &GpuOptions,
) -> Result<wgpu::Adapter, GpuError> {
    let usable: Vec<&wgpu::Adapter> = adapters
        .iter()
        .filter(|a| surface.is_none_or(|s| a.is_surface_supported(s)))
        .collect();
    if let Some(wanted) = &options.adapter_name {
        let needle = wanted.to_lowercase();
        return usable
            .iter()
            .find(|a| a.get_info().name.to_lowercase().contains(&needle))
            .map(|a| (*a).clone())
            .ok_or_else(|| GpuError::NoMatchingAdapter {
                wanted: wanted.clone(),
                available: if usable.is_empty() {
                    "none".into()
                } else {
                    usable
                        .iter()
                        .map(|a| adapter_label(a))
                        .collect::<Vec<_>>()
                        .join(", ")
                },
            });
    }
    usable
        .into_iter()
        .min_by_key(|a| rank(a))
        .cloned()
        .ok_or_else(|| GpuError::NoAdapter {
            backends: format!("{:?}", backends()),
        })
}

/// The device request for an adapter: its optional features and its own limits, so that
/// large storage bindings (up to what the adapter allows) are available.
pub fn device_descriptor(
    adapter: &wgpu::Adapter,
    options: &GpuOptions,
) -> wgpu::DeviceDescriptor<'static> {
    wgpu::DeviceDescriptor {
        label: Some("unica"),
        required_features: Capabilities::for_adapter(adapter, options).features(),
        required_limits: adapter.limits(),
        ..Default::default()
    }
}

/// What a binding of a kernel holds: a whole buffer, or texels ([`texels`]).
#[derive(Clone, Copy, Debug)]
pub enum Bound<'a> {
    Buffer(&'a wgpu::Buffer),
    Texels(&'a texels::Texels),
}

/// A device and queue with the facts the kernels need about them.
#[derive(Clone)]
pub struct GpuContext {
    pub adapter: wgpu::Adapter,
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub caps: Capabilities,
    /// What this device has been asked to do (see [`counters`]).
    pub counters: Arc<Counters>,
}

impl fmt::Debug for GpuContext {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("GpuContext")
            .field("adapter", &adapter_label(&self.adapter))
            .field("caps", &self.caps)
            .finish()
    }
}

impl GpuContext {
    /// A device without a window: tests, command-line tools, benchmarks.
    pub fn headless(options: &GpuOptions) -> Result<Self, GpuError> {
        pollster::block_on(Self::headless_async(options))
    }

    async fn headless_async(options: &GpuOptions) -> Result<Self, GpuError> {
        let adapters = enumerate_adapters().await;
        let adapter = select_adapter(&adapters, None, options)?;
        let (device, queue) = adapter
            .request_device(&device_descriptor(&adapter, options))
            .await
            .map_err(|source| GpuError::Device {
                adapter: adapter_label(&adapter),
                source,
            })?;
        Ok(Self::from_parts(adapter, device, queue))
    }

    /// Wraps a device created elsewhere (the window's) with [`device_descriptor`].
    pub fn from_parts(adapter: wgpu::Adapter, device: wgpu::Device, queue: wgpu::Queue) -> Self {
        let features = device.features();
        let caps = Capabilities {
            shader_f16: features.contains(wgpu::Features::SHADER_F16),
            subgroups: features.contains(wgpu::Features::SUBGROUP),
            timestamps: features.contains(wgpu::Features::TIMESTAMP_QUERY),
        };
        Self {
            adapter,
            device,
            queue,
            caps,
            counters: Arc::new(Counters::default()),
        }
    }

    /// The counts so far (see [`counters`]).
    pub fn counts(&self) -> Counts {
        self.counters.snapshot()
    }

    /// Creates a buffer (counted).
    pub fn create_buffer(&self, descriptor: &wgpu::BufferDescriptor) -> wgpu::Buffer {
        self.counters.buffer();
        self.device.create_buffer(descriptor)
    }

    /// Creates a bind group (counted).
    pub fn create_bind_group(&self, descriptor: &wgpu::BindGroupDescriptor) -> wgpu::BindGroup {
        self.counters.bind_group();
        self.device.create_bind_group(descriptor)
    }

    /// A bind group of `layout` with `resources` at bindings 0, 1, … (counted).
    pub fn bind(&self, layout: &wgpu::BindGroupLayout, resources: &[Bound]) -> wgpu::BindGroup {
        let entries: Vec<wgpu::BindGroupEntry> = resources
            .iter()
            .enumerate()
            .map(|(i, r)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: match r {
                    Bound::Buffer(b) => b.as_entire_binding(),
                    Bound::Texels(t) => wgpu::BindingResource::TextureView(&t.view),
                },
            })
            .collect();
        self.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout,
            entries: &entries,
        })
    }

    /// Submits command buffers to the queue (counted as one submission).
    pub fn submit<I: IntoIterator<Item = wgpu::CommandBuffer>>(
        &self,
        buffers: I,
    ) -> wgpu::SubmissionIndex {
        self.counters.submission();
        self.queue.submit(buffers)
    }

    /// Whether the adapter is a CPU driver (lavapipe, llvmpipe, WARP): the per-adapter
    /// defaults (kernel variant, splat level, window scale, split frames) follow it.
    pub fn cpu_driver(&self) -> bool {
        self.adapter.get_info().device_type == wgpu::DeviceType::Cpu
    }

    /// Human-readable adapter name, backend and device type.
    pub fn adapter_label(&self) -> String {
        adapter_label(&self.adapter)
    }

    /// The largest buffer one storage binding can see on this device.
    pub fn max_storage_binding(&self) -> u64 {
        self.device.limits().max_storage_buffer_binding_size
    }

    /// A storage buffer, refused with a clear error if one binding could not see all of it.
    pub fn storage_buffer(
        &self,
        label: &str,
        size: u64,
        usage: wgpu::BufferUsages,
    ) -> Result<wgpu::Buffer, GpuError> {
        let max = self.max_storage_binding();
        if size > max {
            return Err(GpuError::BufferTooLarge {
                label: label.into(),
                size,
                max,
            });
        }
        Ok(self.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size,
            usage: usage | wgpu::BufferUsages::STORAGE,
            mapped_at_creation: false,
        }))
    }

    /// A storage buffer filled with `data`, padded with zeros to a non-zero multiple of 4
    /// bytes (same size check as [`Self::storage_buffer`]).
    pub fn storage_buffer_init(
        &self,
        label: &str,
        data: &[u8],
        usage: wgpu::BufferUsages,
    ) -> Result<wgpu::Buffer, GpuError> {
        // Bound and copied sizes must be non-zero multiples of 4: pad with zeros.
        let size = data.len().max(1).next_multiple_of(4);
        let buffer =
            self.storage_buffer(label, size as u64, usage | wgpu::BufferUsages::COPY_DST)?;
        if size == data.len() {
            self.queue.write_buffer(&buffer, 0, data);
        } else {
            let mut padded = data.to_vec();
            padded.resize(size, 0);
            self.queue.write_buffer(&buffer, 0, &padded);
        }
        Ok(buffer)
    }

    /// Blocks until all submitted work is done.
    pub fn wait_idle(&self) {
        if let Err(err) = self.device.poll(wgpu::PollType::wait_indefinitely()) {
            log::error!("waiting for the GPU failed: {err}");
        }
    }
}
