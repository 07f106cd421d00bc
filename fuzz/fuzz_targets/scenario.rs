#![no_main]
//! `cargo +nightly fuzz run scenario --features libfuzzer`: see `swarm_fuzz::scenario`.
libfuzzer_sys::fuzz_target!(|data: &[u8]| swarm_fuzz::scenario(data));
