#![no_main]
//! `cargo +nightly fuzz run netem_http --features libfuzzer`: see `swarm_fuzz::netem_http`.
libfuzzer_sys::fuzz_target!(|data: &[u8]| swarm_fuzz::netem_http(data));
