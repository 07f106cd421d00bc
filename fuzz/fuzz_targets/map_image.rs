#![no_main]
//! `cargo +nightly fuzz run map_image --features libfuzzer`: see `swarm_fuzz::map_image`.
libfuzzer_sys::fuzz_target!(|data: &[u8]| swarm_fuzz::map_image(data));
