//! The library's pipeline and its outputs: synthetic scenes, the API, edits, kept objects, image input, perceptual measures, the SVG and the flattened outputs.
//! One binary for the area: one link of the dependency tree serves every test in it.

mod pipeline_support;

mod api;
mod edit_synthetic;
mod flat_output;
mod imageio;
mod keep_objects;
mod perceptual_reference;
mod svg_output;
mod synthetic;
