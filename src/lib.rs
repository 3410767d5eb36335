//! nldenoise: Rousselle et al.'s variance-aware, feature-guided NL-means
//! denoiser for Monte Carlo renderings.
//!
//! Architecture (dependencies flow downward):
//!
//! * [`api`]: entry points (denoise a frame in memory or a file);
//! * [`engine`]: the streaming tiled engine (threads, bounded queues, memory budget);
//! * [`exrio`]: every contact with the `exr` crate, channel roles, frame I/O;
//! * [`filter`]: the pure filter math (SPEC §1–5) on any rectangle of a frame;
//! * [`geom`], [`image`]: frame-coordinate rectangles and planes;
//! * [`metrics`]: relMSE and friends (SPEC §8); [`preview`]: PNG crops;
//! * [`sequence`]: frame sequences for batch runs (`shot.####.exr`, frame lists).
//!
//! ```
//! use nldenoise::{filter, geom::Rect, image::Plane};
//! let frame = Rect::from_origin_size(0, 0, 16, 12);
//! let noisy = |c: usize| Plane::from_fn(frame, move |x, y| ((x * 7 + y * 13 + c as i64) % 5) as f32 * 0.1 + 0.5);
//! let inputs = filter::FrameInputs {
//!     colour: filter::Buffer {
//!         name: "beauty".into(),
//!         values: (0..3).map(noisy).collect(),
//!         variance: filter::VarianceSource::Sample((0..3).map(|_| Plane::filled(frame, 0.01)).collect()),
//!     },
//!     features: vec![],
//!     layers: vec![],
//! };
//! let params = filter::Params { search_radius: 3, patch_radius: 1, ..Default::default() };
//! let out = filter::denoise_region(&inputs, frame, frame, &params).unwrap();
//! assert_eq!(out.colour.len(), 3);
//! ```
#![deny(missing_docs)]

pub mod api;
pub mod engine;
pub mod error;
pub mod exrio;
pub mod filter;
#[doc(hidden)]
pub mod fuzzing;
pub mod geom;
pub mod image;
pub mod metrics;
pub mod preview;
pub mod sequence;

pub use error::{Error, Result};
