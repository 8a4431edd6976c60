//! Appearance (DESIGN §7): Gaussian splats from position maps. Built so far: the world
//! alignment; the splats, refiner and rasterizer are open work (issue #6).

pub mod align;
