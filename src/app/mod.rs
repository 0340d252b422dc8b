//! `app` layer (see DESIGN in the README). Filled in by its own issue.

pub mod live;
