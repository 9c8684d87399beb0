//! Geometry shared by the renderer, the initialiser and the editor.
//!
//! - [`bezier`]: cubic evaluation, Bernstein weights and uniform-parameter flattening.
//! - [`contour`]: contour tracing and polygon simplification on canvas pixels.

pub mod bezier;
pub mod contour;
