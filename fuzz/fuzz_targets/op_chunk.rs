#![no_main]
//! `cargo +nightly fuzz run op_chunk --features libfuzzer`: see `swarm_fuzz::op_chunk`.
libfuzzer_sys::fuzz_target!(|data: &[u8]| swarm_fuzz::op_chunk(data));
