//! The character side (the teacher): loading characters from glTF/GLB and OBJ files.
//! The live neural path (engine, nn) never imports this module.

pub mod character;
pub mod mesh;

pub use character::{Character, load_character};
pub use mesh::Mesh;
