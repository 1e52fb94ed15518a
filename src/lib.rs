//! The `hemodpd` command line as a library: running one scenario (the output directory's lock,
//! the thread pool, the run or its resume, `summary.json`) and sweeps. The CLI (`src/main.rs`)
//! and the Python package (`python/`) both go through here.

pub mod fit;
pub mod run;
pub mod sweep;
