//! The run's secrets, made fresh for every run from the kernel's random bytes and readable by
//! the owner only: netem's API token (`netem.token`, when `netem.api_token = true`) and the sim
//! plane's logins (`secrets/`: the world-server's user dictionary `users` and one
//! `<process>` file per process with its `user:password` line — see `proto::confine`).

use std::io::{Read, Write};
use std::os::unix::fs::{DirBuilderExt, OpenOptionsExt};
use std::path::{Path, PathBuf};

use anyhow::Context;
use proto::confine::{Credentials, Principal};

use super::prepare::Plan;

/// 128 random bits from the kernel, in hex.
fn random_hex() -> anyhow::Result<String> {
    let mut bytes = [0u8; 16];
    std::fs::File::open("/dev/urandom")
        .and_then(|mut f| f.read_exact(&mut bytes))
        .context("reading /dev/urandom")?;
    Ok(bytes.iter().map(|b| format!("{b:02x}")).collect())
}

/// Writes `text` to `path`, readable and writable by the owner only.
fn write_private(path: &Path, text: &str) -> anyhow::Result<()> {
    std::fs::OpenOptions::new()
        .create(true)
        .write(true)
        .truncate(true)
        .mode(0o600)
        .open(path)
        .and_then(|mut f| f.write_all(text.as_bytes()))
        .with_context(|| format!("writing {}", path.display()))
}

/// Writes a new bearer token for netem's API.
pub fn write_token(path: &Path) -> anyhow::Result<()> {
    write_private(path, &format!("{}\n", random_hex()?))
}

/// The directory of the sim plane's logins.
pub fn dir(plan: &Plan) -> PathBuf {
    plan.dir.join("secrets")
}

/// The file with `p`'s login.
pub fn credentials(plan: &Plan, p: Principal) -> PathBuf {
    dir(plan).join(p.to_string())
}

/// The world-server's dictionary of every login.
pub fn users(plan: &Plan) -> PathBuf {
    dir(plan).join("users")
}

/// The principal that runs radio node `id` (a robot or the base station).
pub fn node(plan: &Plan, id: proto::msg::RobotId) -> Principal {
    if plan.scenario.base_id() == Some(id) {
        Principal::BaseStation(id)
    } else {
        Principal::Robot(id)
    }
}

/// Makes a login for every process of the run (and an `observer`, read-only, for tools that
/// watch it).
pub fn write_logins(plan: &Plan) -> anyhow::Result<()> {
    let d = dir(plan);
    std::fs::DirBuilder::new()
        .mode(0o700)
        .create(&d)
        .with_context(|| format!("creating {}", d.display()))?;
    let mut all = String::new();
    for p in Principal::of_run(plan.robots(), plan.scenario.base_id()) {
        let login = Credentials {
            user: p.to_string(),
            password: random_hex()?,
        };
        write_private(&credentials(plan, p), &format!("{}\n", login.line()))?;
        all.push_str(&login.line());
        all.push('\n');
    }
    write_private(&users(plan), &all)
}
