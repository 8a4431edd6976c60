//! Appearance (DESIGN §7): Gaussian splats from position maps. Built so far: the world
//! alignment and the 3DGS PLY format; the splats, refiner and rasterizer are open work
//! (issue #6).

pub mod align;
pub mod ply;
pub mod project;
