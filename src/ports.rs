//! Free loopback ports for the processes of a run, so that several runs (and tests) can go on
//! side by side. A port is taken from the kernel (bind to port 0) and released just before the
//! child binds it; the window is small, and a clash surfaces as a clear child start-up error.

use std::net::TcpListener;

/// `n` distinct free TCP ports on 127.0.0.1.
pub fn free_ports(n: usize) -> std::io::Result<Vec<u16>> {
    // Hold all listeners until every port is chosen, so the kernel gives distinct ones.
    let listeners: Vec<TcpListener> = (0..n)
        .map(|_| TcpListener::bind("127.0.0.1:0"))
        .collect::<Result<_, _>>()?;
    listeners
        .iter()
        .map(|l| l.local_addr().map(|a| a.port()))
        .collect()
}

pub fn endpoint(port: u16) -> String {
    format!("tcp/127.0.0.1:{port}")
}
