//! `app` layer: the commands' use cases, each scheduling the pipeline and the renderers below it —
//! [`offline`] (`render` on a chosen backend, orbit cameras), [`window`] (the `view` loop), [`xr_session`]
//! (`xr`), [`live`] (capture -> pipeline worker, frame dropping, video folders) and [`neural`] (the neural
//! renderer of the interactive paths).

pub mod live;
pub mod live_bench;
pub mod neural;
pub mod offline;
pub mod window;
pub mod xr_session;

pub use crate::gpu::backend::{log_software_device, Backend};
