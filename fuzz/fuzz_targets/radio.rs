#![no_main]
//! `cargo +nightly fuzz run radio --features libfuzzer`: see `swarm_fuzz::radio`.
libfuzzer_sys::fuzz_target!(|data: &[u8]| swarm_fuzz::radio(data));
