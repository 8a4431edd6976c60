//! The engine's own kernels, which keep a generated frame on the GPU after the decode:
//! clamping, the root shift and the root motion (`frame_unit`), the PCA projection (`pca_coefficients`,
//! `frame_points`) and the window's slide as maps with the world root's update (`slide`;
//! the engine encodes them at the next frame's start, turned to the model's heading by
//! `turn`). Their
//! parameter structs are declared once here for Rust and WGSL (`gpu_struct!`); the WGSL
//! is in `shaders/engine/`. CPU references of the same arithmetic are in this module's
//! tests and in `tests/engine.rs`.

use crate::gpu::shaders::Shader;
use crate::gpu_struct;
use crate::wgsl_shader;

/// Threads of the one workgroup of `frame_unit.wgsl` (`@workgroup_size` there).
pub const UNIT_THREADS: u32 = 256;

gpu_struct! {
    /// What the engine's kernels need to know about the bundle and the frame.
    pub struct PostParams {
        /// Foreground pixels of the 128² map (points per frame).
        pub points: u32,
        /// Pixels per map plane (128²).
        pub plane: u32,
        /// Waist pixels (indices into the points).
        pub waist: u32,
        /// PCA components (rows of the basis); 0 draws the clamped points as they are.
        pub components: u32,
        /// The normalisation scale (normalised units per metre).
        pub scale: f32,
        /// Context frames in the window (F-1).
        pub frames: u32,
        /// 1: the root motion is measured from the `reference` map's root
        /// (`RootMotion::Decoded`); 0: from 0.5 (`RootMotion::Centre`).
        pub decoded_reference: u32,
        /// 1: the root motion's height puts the frame's lowest point on the floor, y = 0
        /// (`Manifest::grounded`); 0: it is the root's, like x and z.
        pub grounded: u32,
        /// The stand latch (`Manifest::stand_speed`): under Idle, once a frame's
        /// horizontal root motion is shorter than this (normalised units), the world
        /// root holds still until a movement key; 0: it always moves.
        pub stand: f32,
        pub reserved: u32,
    }
}

gpu_struct! {
    /// The state of the live loop on the GPU, and the few bytes read back per frame.
    pub struct FrameState {
        /// The world root before the latest frame (xyz, metres).
        pub root: [f32; 4],
        /// The latest frame's root shift (xyz, normalised units): the window's slide.
        pub shift: [f32; 4],
        /// The latest frame's root motion (xyz, normalised units): the shift, or with a
        /// decoded reference the root minus the reference map's root.
        pub motion: [f32; 4],
        /// Map values clamped into [0, 1] (or NaN replaced) in the latest frame.
        pub clamped: u32,
        /// The same since the start.
        pub clamped_total: u32,
        /// Frames generated.
        pub frames: u32,
        /// 1 while the stand latch holds the world root (`PostParams::stand`); the
        /// standing start begins held.
        pub standing: u32,
    }
}

gpu_struct! {
    /// The quarter turns about the vertical between the world's frame and the model's
    /// (`engine::bundle::Heading`), written by the CPU before each frame: the window is turned
    /// `to_model` before it is encoded, the new frame `to_world` after it is decoded
    /// (`to_model + to_world` is 0 mod 4); and whether the frame's key is Idle (for the
    /// stand latch, `PostParams::stand`).
    pub struct HeadingTurns {
        pub to_model: u32,
        pub to_world: u32,
        /// 1: the frame's key is Idle.
        pub idle: u32,
        pub reserved: u32,
    }
}

impl HeadingTurns {
    /// The turns for a heading of `quarters` quarter turns from +Z, for a frame whose key
    /// is Idle or not.
    pub fn new(quarters: u32, idle: bool) -> Self {
        Self {
            to_model: (4 - quarters % 4) % 4,
            to_world: quarters % 4,
            idle: u32::from(idle),
            ..bytemuck::Zeroable::zeroed()
        }
    }
}

pub const FRAME_UNIT: Shader = wgsl_shader!(
    "engine/frame_unit.wgsl",
    [PostParams, FrameState, HeadingTurns],
    elem
);
pub const TURN: Shader = wgsl_shader!("engine/turn.wgsl", [PostParams, HeadingTurns], elem)
    .with_uints(&[("BACKGROUND", super::recentre::BACKGROUND)]);
pub const PCA_COEFFICIENTS: Shader = wgsl_shader!("engine/pca_coefficients.wgsl", [PostParams, FrameState], f16: false, subgroups: false);
/// `PCA_COEFFICIENTS` for GPUs: a workgroup per component, its threads splitting the sum.
pub const PCA_COEFFICIENTS_SPLIT: Shader = wgsl_shader!("engine/pca_coefficients_split.wgsl", [PostParams, FrameState], f16: false, subgroups: false);
pub const FRAME_POINTS: Shader = wgsl_shader!("engine/frame_points.wgsl", [PostParams, FrameState], f16: false, subgroups: false);
pub const SLIDE: Shader = wgsl_shader!("engine/slide.wgsl", [PostParams, FrameState], elem)
    .with_uints(&[("BACKGROUND", super::recentre::BACKGROUND)]);

/// Every shader of the engine stage.
pub const ALL: &[Shader] = &[
    FRAME_UNIT,
    PCA_COEFFICIENTS,
    PCA_COEFFICIENTS_SPLIT,
    FRAME_POINTS,
    SLIDE,
    TURN,
];
