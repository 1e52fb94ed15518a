//! The scenario kinds' end-to-end tests, run in-process, one module per kind, in one test binary
//! (`cargo test --test end_to_end <name>`). The tests of the command line, sweeps, fits and
//! resumption, which start `hemodpd` processes, and the walls tests are binaries of their own
//! (Cargo.toml says why).

mod common;

mod capillary;
mod fluid;
mod shear;
mod stress;
mod stretching;
