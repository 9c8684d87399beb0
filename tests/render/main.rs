//! Renderer: gradients, coverage, determinism, DiffVG's references, compositing.
//! One binary for the area: one link of the dependency tree serves every test in it.

mod render_support;

mod composite;
mod coverage;
mod determinism;
mod diffvg;
mod gradients;
