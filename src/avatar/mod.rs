//! The character side (the teacher): loading characters (glTF/GLB, OBJ), rigs, clips and
//! skinning. The live neural path (engine, nn) never imports this module.

pub mod character;
pub mod clip;
pub mod description;
pub mod gait;
pub mod gltf_check;
pub mod hanging;
pub mod humanoid;
pub mod load_error;
pub mod locomotion;
pub mod loose;
pub mod reference;
pub mod rig;
pub mod springs;
pub mod teacher;
pub mod vrm;

pub use character::{Character, CharacterError, load_character, load_character_with};
