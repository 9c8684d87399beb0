//! Geometry shared by the renderer, the initialiser and the editor.
//!
//! - [`bezier`]: cubic evaluation, Bernstein weights and uniform-parameter flattening.

pub mod bezier;
