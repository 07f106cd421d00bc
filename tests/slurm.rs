//! Slurm (docs/guide/slurm.md): a sweep submitted as a job array, and a run whose robots are
//! placed on the nodes of an allocation by `srun`, on a real Slurm cluster the test starts
//! itself from Debian's packages — `munged` with its own key and socket, `slurmctld`, and
//! three `slurmd` nodes (n1, n2, n3) on this one machine, each on its own port
//! (`ProctrackType=proctrack/linuxproc`), every daemon in the foreground under a temporary
//! directory and killed, with every job cancelled, when the test ends.
//!
//! Ignored by default (they need the daemons and root); `.ci/run` installs them and runs these
//! with the other ignored tests. Where they run, a cluster that cannot be started fails the
//! test.

use std::collections::HashMap;
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use crate::support::{csv, free_ports, poll, summary_typed, Launcher, TempDir, SWARM};

/// Why these tests are ignored, and how to get what they need.
const NEEDS: &str = "needs root and Slurm: apt install slurmctld slurmd slurm-client munge";

/// The nodes of the test's cluster.
const NODES: [&str; 3] = ["n1", "n2", "n3"];

/// A one-machine Slurm cluster: its daemons are killed on drop, after every job is cancelled.
struct Cluster {
    dir: TempDir,
    daemons: Vec<Child>,
}

impl Cluster {
    fn start(name: &str) -> Cluster {
        let dir = TempDir::new(name);
        let mut c = Cluster {
            dir,
            daemons: Vec::new(),
        };
        let root = c.dir.path().to_path_buf();
        for sub in ["state", "log", "munge"] {
            std::fs::create_dir_all(root.join(sub)).expect("cluster dirs");
        }
        for n in NODES {
            std::fs::create_dir_all(root.join(format!("spool-{n}"))).expect("spool dir");
        }
        c.start_munge(&root);
        std::fs::write(c.conf(), slurm_conf(&root)).expect("write slurm.conf");
        let conf = c.conf().to_string_lossy().into_owned();
        c.daemon("slurmctld", &["-D", "-i", "-f", &conf]);
        for n in NODES {
            c.daemon("slurmd", &["-D", "-N", n, "-f", &conf]);
        }
        poll(Duration::from_secs(60), Duration::from_millis(300), || {
            let out = c.tool("sinfo", &["--noheader", "--Node", "--format=%N %t"]);
            let idle = out.lines().filter(|l| l.ends_with(" idle")).count();
            (idle == NODES.len()).then_some(()).ok_or(format!(
                "the cluster's nodes are not all idle ({NEEDS}): {out:?}"
            ))
        });
        c
    }

    fn conf(&self) -> PathBuf {
        self.dir.path().join("slurm.conf")
    }

    /// `munged` on its own key and socket, in the foreground.
    fn start_munge(&mut self, root: &Path) {
        let m = root.join("munge");
        std::fs::set_permissions(&m, std::fs::Permissions::from_mode(0o700)).expect("chmod");
        let mut key = vec![0u8; 1024];
        std::io::Read::read_exact(
            &mut std::fs::File::open("/dev/urandom").expect("/dev/urandom"),
            &mut key,
        )
        .expect("read /dev/urandom");
        let key_file = m.join("munge.key");
        std::fs::write(&key_file, key).expect("munge key");
        std::fs::set_permissions(&key_file, std::fs::Permissions::from_mode(0o400))
            .expect("chmod key");
        let arg = |flag: &str, file: &str| format!("--{flag}={}", m.join(file).display());
        let args = [
            "-F".to_string(),
            "--force".into(),
            arg("socket", "munge.socket"),
            arg("key-file", "munge.key"),
            arg("pid-file", "munged.pid"),
            arg("log-file", "munged.log"),
            arg("seed-file", "munged.seed"),
        ];
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        self.daemon("munged", &args);
        poll(Duration::from_secs(20), Duration::from_millis(100), || {
            m.join("munge.socket")
                .exists()
                .then_some(())
                .ok_or(format!("munged made no socket ({NEEDS})"))
        });
    }

    fn daemon(&mut self, program: &str, args: &[&str]) {
        let log = std::fs::File::create(
            self.dir
                .path()
                .join(format!("log/{program}-{}.out", self.daemons.len())),
        )
        .expect("daemon log");
        // The daemons are in /usr/sbin, which a test's PATH may lack.
        let sbin = Path::new("/usr/sbin").join(program);
        let exe = if sbin.exists() {
            sbin
        } else {
            PathBuf::from(program)
        };
        let child = Command::new(exe)
            .args(args)
            .env("SLURM_CONF", self.conf())
            .stdin(Stdio::null())
            .stdout(log.try_clone().expect("log"))
            .stderr(log)
            .spawn()
            .unwrap_or_else(|e| panic!("cannot start {program} ({NEEDS}): {e}"));
        self.daemons.push(child);
    }

    /// A command that talks to this cluster.
    fn command(&self, program: &str) -> Command {
        let mut cmd = Command::new(program);
        cmd.env("SLURM_CONF", self.conf());
        cmd
    }

    /// Runs a Slurm client; what it printed (a failure is a test failure).
    fn tool(&self, program: &str, args: &[&str]) -> String {
        let out = self
            .command(program)
            .args(args)
            .output()
            .unwrap_or_else(|e| panic!("{program} ({NEEDS}): {e}"));
        assert!(
            out.status.success(),
            "{program} {args:?}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8_lossy(&out.stdout).into_owned()
    }

    /// The array tasks of `job` in the queue, by index, with their state.
    fn queue(&self, job: &str) -> HashMap<usize, String> {
        let out = self
            .command("squeue")
            .args(["--noheader", "--array", "--jobs", job, "--format=%K %t"])
            .output()
            .expect("squeue");
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .filter_map(|l| {
                let (k, s) = l.split_once(' ')?;
                Some((k.parse().ok()?, s.trim().to_string()))
            })
            .collect()
    }

    /// Whether any job of the cluster is still in the queue.
    fn busy(&self) -> bool {
        let out = self.command("squeue").arg("--noheader").output();
        out.is_ok_and(|o| !String::from_utf8_lossy(&o.stdout).trim().is_empty())
    }
}

impl Drop for Cluster {
    fn drop(&mut self) {
        let _ = self.command("scancel").args(["--user", "root"]).status();
        for _ in 0..100 {
            if !self.busy() {
                break;
            }
            std::thread::sleep(Duration::from_millis(200));
        }
        for d in self.daemons.iter_mut().rev() {
            let _ = d.kill();
            let _ = d.wait();
        }
    }
}

/// The cluster's `slurm.conf`: this machine's hostname as the controller and as every node's
/// host, free ports, everything under `root`.
fn slurm_conf(root: &Path) -> String {
    let host = std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_string())
        .unwrap_or_else(|_| "localhost".into());
    let ports = free_ports(1 + NODES.len());
    let r = root.display();
    let mut conf = format!(
        "ClusterName=swarmtest\nSlurmctldHost={host}(127.0.0.1)\nSlurmctldPort={}\n\
         SlurmUser=root\nSlurmdUser=root\nAuthType=auth/munge\nCredType=cred/munge\n\
         AuthInfo=socket={r}/munge/munge.socket\nStateSaveLocation={r}/state\n\
         SlurmdSpoolDir={r}/spool-%n\nSlurmctldPidFile={r}/slurmctld.pid\n\
         SlurmdPidFile={r}/slurmd-%n.pid\nSlurmctldLogFile={r}/log/slurmctld.log\n\
         SlurmdLogFile={r}/log/slurmd-%n.log\nProctrackType=proctrack/linuxproc\n\
         TaskPlugin=task/none\nSchedulerType=sched/backfill\nSelectType=select/cons_tres\n\
         SelectTypeParameters=CR_Core\nReturnToService=2\nMpiDefault=none\nKillWait=5\n\
         MailProg=/bin/true\nJobAcctGatherType=jobacct_gather/none\n\
         AccountingStorageType=accounting_storage/none\n",
        ports[0]
    );
    for (n, port) in NODES.iter().zip(&ports[1..]) {
        conf.push_str(&format!(
            "NodeName={n} NodeHostname={host} NodeAddr=127.0.0.1 Port={port} CPUs=1 \
             RealMemory=1000 State=UNKNOWN\n"
        ));
    }
    conf.push_str("PartitionName=debug Nodes=ALL Default=YES MaxTime=INFINITE State=UP\n");
    conf
}

/// The quick E3 sweep (what `.ci/run` runs) into `out`, with more flags.
fn quick_e3(cmd: &mut Command, out: &Path, more: &[&str]) {
    let exp = Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/experiments/e3-traffic.toml");
    cmd.arg("sweep")
        .arg(exp)
        .arg("--quick")
        .arg("--out")
        .arg(out)
        .args(more);
}

/// runs.csv without its wall-clock column, in order.
fn runs_but_wall(out: &Path) -> Vec<Vec<(String, String)>> {
    csv(&out.join("runs.csv"))
        .into_iter()
        .map(|r| {
            let mut row: Vec<(String, String)> =
                r.into_iter().filter(|(k, _)| k != "wall_seconds").collect();
            row.sort();
            row
        })
        .collect()
}

/// The run directories of submission `n` of the sweep in `out`, in array order, and its job.
fn submission(out: &Path, n: usize) -> (String, Vec<PathBuf>) {
    let text = std::fs::read_to_string(out.join(format!("slurm/submit-{n}.json")))
        .unwrap_or_else(|e| panic!("submission {n}: {e}"));
    let v: serde_json::Value = serde_json::from_str(&text).expect("submission json");
    let job = v["job"].as_str().unwrap_or_default().to_string();
    let dirs = (v["tasks"].as_array().expect("tasks").iter())
        .map(|t| PathBuf::from(t["dir"].as_str().expect("dir")))
        .collect();
    (job, dirs)
}

fn finished(dir: &Path) -> bool {
    swarm::rundir::summary::finished(dir)
}

/// Cancels a running task of the array whose run has not finished, and returns its run
/// directory: one that finished before the cancel reached it is passed over for the next.
fn cancel_a_running_task(cluster: &Cluster, out: &Path) -> PathBuf {
    let (job, dirs) = poll(Duration::from_secs(60), Duration::from_millis(100), || {
        if !out.join("slurm/submit-1.json").exists() {
            return Err("nothing submitted yet".to_string());
        }
        let (job, dirs) = submission(out, 1);
        (!job.is_empty())
            .then_some((job, dirs))
            .ok_or("no job yet".to_string())
    });
    poll(Duration::from_secs(240), Duration::from_millis(50), || {
        let q = cluster.queue(&job);
        let Some(k) = (q.iter())
            .filter(|(k, s)| s.as_str() == "R" && !dirs[**k].join("summary.json").exists())
            .map(|(k, _)| *k)
            .min()
        else {
            return Err(format!("no task of {job} running: {q:?}"));
        };
        cluster.tool("scancel", &[&format!("{job}_{k}")]);
        std::thread::sleep(Duration::from_secs(2));
        if finished(&dirs[k]) {
            return Err(format!("task {job}_{k} finished before its cancel"));
        }
        Ok(dirs[k].clone())
    })
}

#[test]
#[ignore = "needs root and Slurm: apt install slurmctld slurmd slurm-client munge"]
fn a_sweep_runs_as_a_job_array_and_resubmitting_runs_only_the_cancelled_task() {
    let cluster = Cluster::start("slurm-sweep");
    let local = cluster.dir.path().join("local");
    let mut cmd = Command::new(SWARM);
    quick_e3(&mut cmd, &local, &["--jobs", "2"]);
    let o = Launcher::spawn(cmd).wait_output(Duration::from_secs(600));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    let out = cluster.dir.path().join("slurm");
    let sweep = || {
        let mut cmd = cluster.command(SWARM);
        quick_e3(&mut cmd, &out, &["--slurm", "--jobs", "2"]);
        Launcher::spawn(cmd)
    };
    let first = sweep();
    let cancelled = cancel_a_running_task(&cluster, &out);
    let o = first.wait_output(Duration::from_secs(600));
    let said = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{said}");
    let (job, dirs) = submission(&out, 1);
    assert_eq!(dirs.len(), 12, "the quick E3 sweep is 12 runs: {dirs:?}");
    let unfinished: Vec<&PathBuf> = dirs.iter().filter(|d| !finished(d)).collect();
    assert_eq!(unfinished, [&cancelled], "{said}");
    let k = dirs
        .iter()
        .position(|d| *d == cancelled)
        .expect("cancelled task");
    assert!(
        said.contains(&format!("task {job}_{k}")) && said.contains(&format!("{job}_{k}.out")),
        "the failed task is named with its Slurm id and output: {said}"
    );
    let o = sweep().wait_output(Duration::from_secs(600));
    let said = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(o.status.success(), "{said}");
    assert!(said.contains("1 runs to submit"), "{said}");
    let (_, again) = submission(&out, 2);
    assert_eq!(
        again,
        [cancelled],
        "only the cancelled run is submitted again"
    );
    assert_eq!(
        runs_but_wall(&out),
        runs_but_wall(&local),
        "the sweep on Slurm gives the local sweep's runs.csv"
    );
}

/// An sbatch script in `dir` that runs `swarm run --hosts slurm` into `run` with `sets`.
fn run_script(dir: &Path, run: &Path, sets: &[&str]) -> PathBuf {
    let script = dir.join(format!(
        "{}.sh",
        run.file_name().expect("name").to_string_lossy()
    ));
    let sets: String = sets.iter().map(|s| format!(" --set {s}")).collect();
    std::fs::write(
        &script,
        format!(
            "#!/bin/sh\nexec {SWARM} run --quiet --hosts slurm --out {}{sets}\n",
            run.display()
        ),
    )
    .expect("write script");
    script
}

/// sbatch `script` on every node; the job id.
fn sbatch_on_all(cluster: &Cluster, script: &Path) -> String {
    let nodes = format!("--nodes={}", NODES.len());
    let output = format!("--output={}.out", script.display());
    let answer = cluster.tool(
        "sbatch",
        &["--parsable", &nodes, &output, &script.to_string_lossy()],
    );
    answer
        .trim()
        .split(';')
        .next()
        .unwrap_or_default()
        .to_string()
}

/// The processes whose command line names `run` (a run's every process does: its directory).
fn processes_of(run: &Path) -> Vec<u32> {
    let needle = run.to_string_lossy().into_owned();
    let me = std::process::id();
    (std::fs::read_dir("/proc").into_iter().flatten().flatten())
        .filter_map(|e| e.file_name().to_str()?.parse::<u32>().ok())
        .filter(|&p| p != me)
        .filter(|p| {
            std::fs::read(format!("/proc/{p}/cmdline"))
                .is_ok_and(|c| String::from_utf8_lossy(&c).contains(&needle))
        })
        .collect()
}

/// `KEY=value` of a process's environment.
fn env_of(pid: u32, key: &str) -> Option<String> {
    let env = std::fs::read(format!("/proc/{pid}/environ")).ok()?;
    let prefix = format!("{key}=");
    env.split(|&b| b == 0)
        .map(String::from_utf8_lossy)
        .find_map(|kv| kv.strip_prefix(&prefix).map(String::from))
}

#[test]
#[ignore = "needs root and Slurm: apt install slurmctld slurmd slurm-client munge"]
fn a_run_in_an_allocation_places_robots_with_srun_and_scancel_leaves_nothing() {
    let cluster = Cluster::start("slurm-run");
    let dir = cluster.dir.path();
    let alone = dir.join("alone");
    let mut cmd = Command::new(SWARM);
    crate::support::run_args(&mut cmd, &alone, &["robots.count=4"]);
    let o = Launcher::spawn(cmd).wait_output(Duration::from_secs(120));
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    // The same run, its robots round-robin over n1 (the batch script's node), n2 and n3.
    let placed = dir.join("placed");
    let job = sbatch_on_all(&cluster, &run_script(dir, &placed, &["robots.count=4"]));
    poll(Duration::from_secs(180), Duration::from_millis(300), || {
        (!cluster.busy())
            .then_some(())
            .ok_or(format!("job {job} still queued"))
    });
    let log = std::fs::read_to_string(dir.join("placed.sh.out")).unwrap_or_default();
    assert!(placed.join("summary.json").exists(), "{log}");
    assert_eq!(
        summary_typed(&placed).run_digest,
        summary_typed(&alone).run_digest,
        "placed by srun, the run is the one-host run: {log}"
    );

    // A longer run: its robots on n2 and n3 are steps of the job; scancel ends them all.
    let long = dir.join("long");
    let sets = ["robots.count=4", "world.map=mit_killian_court"];
    let job = sbatch_on_all(&cluster, &run_script(dir, &long, &sets));
    let stepped = poll(Duration::from_secs(120), Duration::from_millis(200), || {
        let robots: Vec<(String, Option<String>, Option<String>)> = (processes_of(&long)
            .into_iter())
        .filter_map(|p| {
            let cmdline = std::fs::read(format!("/proc/{p}/cmdline")).ok()?;
            let words: Vec<String> = (cmdline.split(|&b| b == 0))
                .map(|w| String::from_utf8_lossy(w).into_owned())
                .collect();
            // The robot itself, not its `on-host` leash or `srun`.
            let i = words.iter().position(|w| w == "--id")?;
            (words.get(1).map(String::as_str) == Some("robot-agent")).then(|| {
                (
                    words[i + 1].clone(),
                    env_of(p, "SLURMD_NODENAME"),
                    env_of(p, "SLURM_STEP_ID"),
                )
            })
        })
        .collect();
        (robots.len() == 4)
            .then_some(robots.clone())
            .ok_or(format!("robots running: {robots:?}"))
    });
    for (id, node, step) in &stepped {
        let want = NODES[id.parse::<usize>().expect("id") % NODES.len()];
        assert_eq!(node.as_deref(), Some(want), "robot {id}: {stepped:?}");
        if want != "n1" {
            assert!(
                step.is_some(),
                "robot {id} is a step of job {job}: {stepped:?}"
            );
        }
    }
    cluster.tool("scancel", &[&job]);
    poll(Duration::from_secs(60), Duration::from_millis(200), || {
        let left = processes_of(&long);
        left.is_empty()
            .then_some(())
            .ok_or(format!("still running after scancel: {left:?}"))
    });
}
