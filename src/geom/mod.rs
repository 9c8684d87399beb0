//! Plane geometry on canvas pixels: contour tracing and polygon simplification.

pub mod contour;
