//! Drawing the scene with wgpu render pipelines: lit meshes and the ground grid, into an
//! off-screen target that the viewport shows, the recorder saves and headless renders read.

pub mod blit;
pub mod camera;
pub mod composite;
pub mod offscreen;
pub mod scene;

pub use camera::OrbitCamera;
pub use scene::{COLOR_FORMAT, GpuMesh, RenderTarget, SceneRenderer, SceneUniforms};
