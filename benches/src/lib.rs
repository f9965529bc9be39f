//! Benchmarks live in `benches/kernels.rs`; this library is empty.
