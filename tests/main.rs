//! Integration tests of swarm-explore: every test launches real processes (the `swarm` binary and
//! the world-server and robot-agent processes it starts) talking zenoh over loopback TCP on free
//! ports. Each test is bounded in time and kills everything it started, also when it fails.

mod capture;
mod support;

mod bids;
mod browser;
mod bypass;
mod chaos;
mod cli;
mod confine;
mod determinism;
mod export;
mod foxglove_live;
mod hosts;
mod layout;
mod lifecycle;
mod mapping;
mod netem;
mod pack;
mod polygon;
mod process_faults;
mod robot_map;
mod roles;
mod runs;
mod slurm;
mod standalone;
mod sweep;
mod toxiproxy_client;
mod view;
mod wire;
