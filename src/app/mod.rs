//! `app` layer: live loops that schedule the pipeline (desktop mirror, XR session, capture).

pub mod live;
pub mod mirror;
pub mod neural;
pub mod xr_session;
