#![no_main]
//! `cargo +nightly fuzz run sim_plane --features libfuzzer`: see `swarm_fuzz::sim_plane`.
libfuzzer_sys::fuzz_target!(|data: &[u8]| swarm_fuzz::sim_plane(data));
