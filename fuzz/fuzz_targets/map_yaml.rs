#![no_main]
//! `cargo +nightly fuzz run map_yaml --features libfuzzer`: see `swarm_fuzz::map_yaml`.
libfuzzer_sys::fuzz_target!(|data: &[u8]| swarm_fuzz::map_yaml(data));
