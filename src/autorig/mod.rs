//! The auto-rigger (UniRig): from a static character mesh to a rigged, animated glTF the
//! teacher can bake — skeleton-tree tokens, synthetic training characters, the voxel
//! geodesic prior, the skeleton and skin models, retargeting and the glTF writer. Part
//! of the teacher side: the live path never imports it.

pub mod data;
pub mod evaluate;
pub mod gltf_out;
pub mod metrics;
pub mod model;
pub mod pipeline;
pub mod retarget;
pub mod skeleton;
pub mod smoothing;
pub mod spring_chains;
pub mod synth;
mod synth_mesh;
mod synth_skeleton;
pub mod tokens;
pub mod voxel;
