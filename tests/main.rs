//! The library's integration tests as one test binary (one link of the library
//! instead of one per file): each file of tests/ is a module, tests/common/ holds the
//! shared harness and the f64 CPU references. Run one file's tests with
//! `cargo test --release --test suite -- sort::` (a module path filter).

mod common;

mod adapt;
mod adapt_stats;
mod borrowed;
mod capture;
mod checkpoint;
mod data;
// The f64 references index like the formulas they spell out.
#[allow(clippy::needless_range_loop)]
mod field;
mod host;
mod loss;
mod mesh;
mod optim;
mod parity;
mod properties;
mod raster;
#[allow(clippy::needless_range_loop)]
mod reference_grad;
mod sort;
mod ssim;
mod svraster_import;
mod topology;
mod train;
mod train_grad;
mod viewer;
