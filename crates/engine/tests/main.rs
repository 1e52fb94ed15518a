//! The engine's integration tests, one module per topic, compiled into one test binary:
//! `cargo test -p hemodpd-engine --test engine` runs them all, `... --test engine -- physics::`
//! one topic. One binary compiles and links the engine's generic code once, not once per file,
//! which keeps the cold build of CI short.

mod capillary_fluid;
mod common;
mod dense_fluid;
mod determinism;
mod errors;
mod extension;
mod lees_edwards;
mod physics;
mod viscosity;
