//! rogs: road-surface mapping with 2D Gaussian surfels on a meshgrid along the
//! trajectory, optimised by differentiable rendering in WebGPU compute shaders.
//!
//! The data path, one module per stage: bundle → grid → init → render → loss →
//! optim → bev → export (see docs/ARCHITECTURE.md for what exists today).

pub mod bev;
pub mod bundle;
pub mod eval;
pub mod export;
#[cfg(not(target_arch = "wasm32"))]
pub mod fuzzing;
pub mod gpu;
pub mod grid;
#[cfg(not(target_arch = "wasm32"))]
pub mod import;
pub mod init;
pub mod linalg;
pub mod loss;
pub mod mem;
pub mod optim;
pub mod par;
pub mod reconstruct;
pub mod render;
#[cfg(any(not(target_arch = "wasm32"), feature = "segmenter"))]
pub mod segment;
pub mod settings;
pub mod spatial;
pub mod synth;
pub mod tiles;

#[cfg(not(target_arch = "wasm32"))]
pub mod cli;

#[cfg(all(target_arch = "wasm32", not(feature = "segmenter")))]
pub mod web;
/// The page's segmentation module is another build of this crate (feature
/// `segmenter`): its bindings are only those of `src/web/segment.rs`.
#[cfg(all(target_arch = "wasm32", feature = "segmenter"))]
#[path = "web/segment.rs"]
pub mod web;
