//! Six-view position maps (docs/architecture.md, Position maps): a fixed pixel →
//! (triangle, barycentrics) table of the reference mesh, the per-frame gather, group
//! normalisation and the inverse. Plain data and math: no GPU, no rig.

pub mod normalize;
pub mod table;

pub use normalize::{GroupNorm, NormError};
pub use table::{MAP_SIZE, SurfaceTable, View};
