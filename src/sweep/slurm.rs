//! A sweep as a Slurm job array (`swarm sweep --slurm`, docs/guide/slurm.md): every run that is
//! not finished, and not still queued by an earlier submission, is one task of one array. A task
//! is `swarm sweep-task SUBMISSION INDEX`, which runs that run's `swarm run` into the sweep
//! directory exactly as a local sweep would. The sweep then waits for the array (unless told not
//! to), names the tasks that ended without finishing their run — with their Slurm id and where
//! their output is — and the runner writes the results as after a local sweep.
//!
//! Under the sweep directory, `slurm/` keeps each submission: `submit-N.json` (the Slurm job id
//! and the tasks, in array order), `submit-N.sh` (the batch script) and each task's output,
//! `JOBID_INDEX.out`. A submission is what makes re-submitting resumable: a run whose task is
//! still in Slurm's queue is not submitted again; a finished run never is.
//!
//! **Invariant:** a run is submitted at most once while a task of it is in Slurm's queue.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use serde::{Deserialize, Serialize};

use crate::process::remote::quote;
use crate::process::slurm::tool;
use crate::run::progress::Progress;
use crate::rundir::summary::finished;

/// One run of a sweep, as a task of a job array.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Task {
    /// Its grid point and seed, for messages.
    pub label: String,
    /// Its run directory.
    pub dir: PathBuf,
    /// `swarm run …`: the words after the binary.
    pub argv: Vec<String>,
}

/// One `sbatch` of a sweep: the array's job id (once Slurm gave it) and its tasks in order.
#[derive(Debug, Serialize, Deserialize)]
struct Submission {
    job: Option<String>,
    tasks: Vec<Task>,
}

/// How to submit: the sweep's name and directory, more sbatch options, how many tasks may
/// run at once (the array's `%` limit), and whether to wait for the array to end.
pub struct Options<'a> {
    pub name: &'a str,
    pub out: &'a Path,
    pub sbatch: &'a [String],
    pub at_once: Option<usize>,
    pub wait: bool,
}

/// A task of a submitted array: its job id, index, and run.
type Queued = (String, usize, Task);

/// Submits the runs of `todo` (those not finished) that no earlier submission still has in
/// Slurm's queue, as one job array; then waits for every task of the sweep in the queue, if
/// `opts.wait`. Returns whether it waited (and the results can be written).
pub fn submit(opts: &Options, todo: Vec<Task>) -> anyhow::Result<bool> {
    let dir = absolute(&opts.out.join("slurm"))?;
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let earlier = submissions(&dir)?;
    let mut watch: Vec<Queued> = Vec::new();
    for (_, s) in &earlier {
        let Some(job) = &s.job else { continue };
        let queued = queue(job)?;
        watch.extend(
            (s.tasks.iter().enumerate())
                .filter(|(i, _)| queued.contains_key(i))
                .map(|(i, t)| (job.clone(), i, t.clone())),
        );
    }
    let queued: BTreeSet<&Path> = watch.iter().map(|(_, _, t)| t.dir.as_path()).collect();
    let fresh: Vec<Task> = (todo.into_iter())
        .filter(|t| !queued.contains(t.dir.as_path()))
        .collect();
    eprintln!(
        "swarm sweep {} on Slurm: {} runs to submit, {} still in the queue from earlier submissions",
        opts.name,
        fresh.len(),
        watch.len()
    );
    if !fresh.is_empty() {
        let job = sbatch(opts, &dir, earlier.len() + 1, &fresh)?;
        eprintln!(
            "submitted as Slurm job array {job} (tasks 0-{}); task output in {}",
            fresh.len() - 1,
            dir.display()
        );
        watch.extend((fresh.into_iter().enumerate()).map(|(i, t)| (job.clone(), i, t)));
    }
    if watch.is_empty() {
        return Ok(true);
    }
    if !opts.wait {
        let jobs: BTreeSet<&str> = watch.iter().map(|(j, _, _)| j.as_str()).collect();
        eprintln!(
            "not waiting: once `squeue -j {}` lists nothing, the same `swarm sweep` with --collect \
             (instead of --slurm) writes the results",
            jobs.into_iter().collect::<Vec<_>>().join(",")
        );
        return Ok(false);
    }
    wait(&watch)?;
    report_failed(&watch, &dir);
    Ok(true)
}

/// The directory's earlier submissions, in order (`submit-1.json`, `submit-2.json`, …).
fn submissions(dir: &Path) -> anyhow::Result<Vec<(PathBuf, Submission)>> {
    let mut out = Vec::new();
    for n in 1.. {
        let file = dir.join(format!("submit-{n}.json"));
        let Ok(text) = std::fs::read_to_string(&file) else {
            break;
        };
        let s: Submission = serde_json::from_str(&text)
            .with_context(|| format!("{} is not a sweep's submission", file.display()))?;
        out.push((file, s));
    }
    Ok(out)
}

/// Writes submission `n` (its tasks and batch script) and submits it with `sbatch`; returns the
/// job id.
fn sbatch(opts: &Options, dir: &Path, n: usize, tasks: &[Task]) -> anyhow::Result<String> {
    let manifest = dir.join(format!("submit-{n}.json"));
    let script = dir.join(format!("submit-{n}.sh"));
    let mut s = Submission {
        job: None,
        tasks: tasks.to_vec(),
    };
    write_json(&manifest, &s)?;
    let exe = std::env::current_exe().context("locating the swarm binary")?;
    let text = format!(
        "#!/bin/sh\n# swarm sweep {}: submission {n}; array task i runs the i-th run of {}\n\
         exec {} sweep-task {} \"$SLURM_ARRAY_TASK_ID\"\n",
        opts.name,
        manifest.display(),
        quote(&exe.to_string_lossy()),
        quote(&manifest.to_string_lossy())
    );
    std::fs::write(&script, text).with_context(|| format!("writing {}", script.display()))?;
    let limit = opts.at_once.map_or(String::new(), |k| format!("%{k}"));
    let cwd = std::env::current_dir().context("reading the working directory")?;
    let mut args = vec![
        "--parsable".to_string(),
        format!("--array=0-{}{limit}", tasks.len() - 1),
        format!("--job-name=swarm-{}", opts.name),
        format!("--output={}/%A_%a.out", dir.display()),
        format!("--chdir={}", cwd.display()),
    ];
    args.extend(opts.sbatch.iter().cloned());
    args.push(script.to_string_lossy().into_owned());
    let answer = tool("sbatch", &args)?;
    let job = job_id(&answer).with_context(|| format!("sbatch answered {answer:?}"))?;
    s.job = Some(job.clone());
    write_json(&manifest, &s)?;
    Ok(job)
}

/// The job id in `sbatch --parsable`'s answer (`123` or `123;cluster`).
fn job_id(answer: &str) -> Option<String> {
    let id = answer.trim().split(';').next()?.trim();
    (!id.is_empty() && id.bytes().all(|b| b.is_ascii_digit())).then(|| id.to_string())
}

/// Writes a submission whole (a reader never finds half of one).
fn write_json(file: &Path, s: &Submission) -> anyhow::Result<()> {
    let part = file.with_extension("json.part");
    std::fs::write(&part, serde_json::to_string_pretty(s)?)
        .and_then(|()| std::fs::rename(&part, file))
        .with_context(|| format!("writing {}", file.display()))
}

/// The tasks of job array `job` in Slurm's queue, with their state (`PD`, `R`, `CG`, …); none
/// once Slurm has forgotten the job.
fn queue(job: &str) -> anyhow::Result<BTreeMap<usize, String>> {
    let args = ["--noheader", "--array", "--jobs", job, "--format=%K %t"].map(String::from);
    match tool("squeue", &args) {
        Ok(out) => Ok(parse_queue(&out)),
        Err(e) if format!("{e:#}").contains("Invalid job id") => Ok(BTreeMap::new()),
        Err(e) => Err(e),
    }
}

/// `squeue --array --format="%K %t"`'s lines: task index and state.
fn parse_queue(out: &str) -> BTreeMap<usize, String> {
    out.lines()
        .filter_map(|l| {
            let mut w = l.split_whitespace();
            Some((w.next()?.parse().ok()?, w.next()?.to_string()))
        })
        .collect()
}

/// How often the queue is asked while waiting.
const POLL: Duration = Duration::from_secs(2);

/// How many times in a row the queue may not answer before waiting gives up.
const QUEUE_RETRIES: u32 = 30;

/// Waits until no task of `watch` is in Slurm's queue, showing progress.
fn wait(watch: &[Queued]) -> anyhow::Result<()> {
    let jobs: BTreeSet<&str> = watch.iter().map(|(j, _, _)| j.as_str()).collect();
    let mut progress = Progress::every_state();
    let started = Instant::now();
    let mut failures = 0;
    loop {
        let mut states: BTreeMap<String, usize> = BTreeMap::new();
        for job in &jobs {
            match queue(job) {
                Ok(q) => {
                    failures = 0;
                    for s in q.into_values() {
                        *states.entry(s).or_default() += 1;
                    }
                }
                Err(e) if failures < QUEUE_RETRIES => {
                    failures += 1;
                    eprintln!("warning: {e:#} (asking again)");
                }
                Err(e) => bail!("Slurm's queue does not answer: {e:#}"),
            }
        }
        let done = watch.iter().filter(|(_, _, t)| finished(&t.dir)).count();
        let queued: Vec<String> = states.iter().map(|(s, n)| format!("{n} {s}")).collect();
        progress.show(&format!(
            "{done}/{} runs finished, {} in the queue ({}), {}s",
            watch.len(),
            states.values().sum::<usize>(),
            queued.join(", "),
            started.elapsed().as_secs()
        ));
        if states.is_empty() {
            progress.finish();
            return Ok(());
        }
        std::thread::sleep(POLL);
    }
}

/// Says which tasks ended without finishing their run, with their Slurm id and where to look.
fn report_failed(watch: &[Queued], dir: &Path) {
    let failed: Vec<&Queued> = watch.iter().filter(|(_, _, t)| !finished(&t.dir)).collect();
    if failed.is_empty() {
        return;
    }
    eprintln!(
        "{} Slurm tasks ended without finishing their run (submit the sweep again to run them):",
        failed.len()
    );
    for (job, i, t) in failed {
        eprintln!(
            "  {}: task {job}_{i}, output {}, the run's logs {}",
            t.label,
            dir.join(format!("{job}_{i}.out")).display(),
            t.dir.join("logs").display()
        );
    }
}

/// `path` from the root: the batch script and the tasks do not share the submitter's working
/// directory's meaning unless told.
fn absolute(path: &Path) -> anyhow::Result<PathBuf> {
    std::path::absolute(path).with_context(|| format!("resolving {}", path.display()))
}

/// `swarm sweep-task` flags: what one task of a sweep's job array runs.
#[derive(clap::Args, Debug)]
pub struct TaskArgs {
    /// The submission (`slurm/submit-N.json` under the sweep directory).
    pub submission: PathBuf,
    /// The task's index in it (`$SLURM_ARRAY_TASK_ID`).
    pub index: usize,
}

/// `swarm sweep-task`: runs the task's run afresh (its directory emptied first, as a local
/// sweep does) with its output here; exit code 0 when the run finished (an exploration that
/// ended incomplete is a finished run), 1 otherwise.
pub fn task_command(args: &TaskArgs) -> anyhow::Result<std::process::ExitCode> {
    let file = &args.submission;
    let text =
        std::fs::read_to_string(file).with_context(|| format!("reading {}", file.display()))?;
    let s: Submission = serde_json::from_str(&text)
        .with_context(|| format!("{} is not a sweep's submission", file.display()))?;
    let Some(task) = s.tasks.get(args.index) else {
        bail!(
            "{} has {} tasks, no task {}",
            file.display(),
            s.tasks.len(),
            args.index
        );
    };
    println!(
        "swarm sweep-task: {} into {}",
        task.label,
        task.dir.display()
    );
    match std::fs::remove_dir_all(&task.dir) {
        Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
            return Err(e).with_context(|| format!("emptying {}", task.dir.display()));
        }
        _ => {}
    }
    let exe = std::env::current_exe().context("locating the swarm binary")?;
    let status = std::process::Command::new(exe)
        .args(&task.argv)
        .status()
        .context("starting swarm run")?;
    if finished(&task.dir) {
        return Ok(std::process::ExitCode::SUCCESS);
    }
    bail!(
        "the run did not finish ({status}): see {}",
        task.dir.join("logs").display()
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_job_id_is_read_from_sbatchs_parsable_answer() {
        assert_eq!(job_id("4242\n").as_deref(), Some("4242"));
        assert_eq!(job_id("4242;cluster\n").as_deref(), Some("4242"));
        for bad in ["", "Submitted batch job 4242", "sbatch: error"] {
            assert_eq!(job_id(bad), None, "{bad:?}");
        }
    }

    #[test]
    fn the_queue_lists_each_task_with_its_state() {
        let q = parse_queue("0 R\n1 R\n5 PD\nN/A R\n\n");
        assert_eq!(
            q,
            BTreeMap::from([
                (0, "R".to_string()),
                (1, "R".to_string()),
                (5, "PD".to_string())
            ])
        );
    }

    #[test]
    fn submissions_are_read_in_order_until_the_first_gap() {
        let dir = std::env::temp_dir().join(format!("swarm-slurm-subs-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap_or_else(|e| panic!("{e}"));
        let task = |k: u32| Task {
            label: format!("p seed {k}"),
            dir: PathBuf::from(format!("runs/p-seed{k}")),
            argv: vec!["run".into()],
        };
        for (n, job) in [(1, Some("7")), (2, None), (4, Some("9"))] {
            let s = Submission {
                job: job.map(String::from),
                tasks: vec![task(n)],
            };
            write_json(&dir.join(format!("submit-{n}.json")), &s).unwrap_or_else(|e| panic!("{e}"));
        }
        let subs = submissions(&dir).unwrap_or_else(|e| panic!("{e}"));
        std::fs::write(dir.join("submit-3.json"), "{").unwrap_or_else(|e| panic!("{e}"));
        let broken = submissions(&dir).map_err(|e| format!("{e:#}"));
        let _ = std::fs::remove_dir_all(&dir);
        let jobs: Vec<Option<&str>> = subs.iter().map(|(_, s)| s.job.as_deref()).collect();
        assert_eq!(jobs, [Some("7"), None]);
        assert_eq!(subs[1].1.tasks, [task(2)]);
        assert!(broken.is_err_and(|e| e.contains("submit-3.json")));
    }
}
