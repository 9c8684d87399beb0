//! covec: photographs to layered, editable SVG (albedo × shade + light), after the COVec paper.
//!
//! One [`scene::Scene`] model feeds the differentiable [`render`]er, the SVG writer and the
//! editor. The [`pipeline`] turns an image into a scene in named stages; [`service`] serves it
//! over HTTP.

pub mod decompose;
pub mod edit;
pub mod eval;
pub mod geom;
pub mod imageio;
pub mod optim;
pub mod perceptual;
pub mod pipeline;
pub mod render;
pub mod scene;
pub mod service;
pub mod svg;
pub mod synth;
pub mod web;
