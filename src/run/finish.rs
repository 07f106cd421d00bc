//! The end of a run: everyone stopped and reaped, then the run directory written — the
//! summary, the tables, the pictures and every robot's final grids.

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::Context;
use proto::exit::ExitReason;
use proto::grid::Grid;
use proto::keys;
use proto::msg::{decode, encode, log_owner, Control, LinkReport, RobotId, Status, Telemetry};
use proto::scenario::{ClockMode, Process};
use zenoh::qos::CongestionControl;

use super::follow::Record;
use super::prepare::Plan;
use super::spawn::Started;
use std::collections::BTreeMap;

use crate::process::children::{MemoryRow, ProcessRow};
use crate::run::progress::Progress;
use crate::rundir::grids::write_map;
use crate::rundir::render::{robot_colour, Picture};
use crate::rundir::summary::{
    bytes_by_type, coverage_steps, traffic_shares, LostLog, Summary, SCHEMA_VERSION,
};
use crate::rundir::tables::link_totals_wire;
use crate::score::connectivity::check_judgements;
use crate::score::evaluate::Evaluator;

/// Tells everyone to stop, waits for every child (killing what does not stop), and collects the
/// link reports that arrived meanwhile.
/// Returns every process the run started (`processes.csv`) and their memory over the run
/// (`memory.csv`).
pub async fn stop(
    run: Started,
    rec: &mut Record,
    progress: &mut Progress,
) -> (Vec<ProcessRow>, Vec<MemoryRow>) {
    let Started {
        mut children, sim, ..
    } = run;
    // A frozen process could not hear the stop.
    for p in rec.sup.frozen().collect::<Vec<_>>() {
        children.signal(&p.to_string(), libc::SIGCONT);
    }
    let _ = sim
        .session
        .put(keys::CONTROL, encode(&Control::Stop))
        .congestion_control(CongestionControl::Block)
        .await;
    children.sample_memory(None);
    let killed = children.shutdown(Duration::from_secs(5)).await;
    // Link reports that arrived while the processes were stopping.
    while let Ok(Some(r)) = sim.link_reports.try_recv() {
        if let Ok(r) = decode::<LinkReport>(&r.payload().to_bytes()) {
            rec.tables.report(r);
        }
    }
    for name in killed {
        progress.event(&format!(
            "swarm run: {name} did not stop within 5 s and was killed"
        ));
    }
    proto::node::close_quickly(sim.session).await;
    (children.table(), children.memory().to_vec())
}

/// `summary.json`'s content, once every step is written.
pub fn summary(plan: &Plan, rec: &Record, exit_reason: ExitReason, started: Instant) -> Summary {
    let eval = &rec.eval;
    let tally = &rec.tables.tally;
    let links = &rec.tables.links;
    let last = rec.last_status().cloned().unwrap_or(Status {
        step: 0,
        robots: Vec::new(),
        collisions_total: 0,
        blocked_total: 0,
        base: None,
        missed: Vec::new(),
    });
    // Every robot's last report, and what its earlier lives (if it was restarted) had sent.
    let earlier = earlier_lives(rec);
    let per_robot_types: Vec<Vec<u64>> = eval
        .last
        .values()
        .map(|l| l.t.sent_by_type.clone())
        .chain(earlier.iter().map(|l| l.sent_by_type.clone()))
        .collect();
    let by_type = bytes_by_type(&per_robot_types);
    let (backlog_max_bytes, backlog_mean_bytes) = tally.backlogs();
    Summary {
        schema_version: SCHEMA_VERSION,
        complete: eval.exploration_step.is_some(),
        exit_reason,
        robots: plan.robots(),
        robots_alive_at_end: last.robots.iter().filter(|r| r.alive).count(),
        steps: last.step,
        wall_seconds: started.elapsed().as_secs_f64(),
        exploration_steps: eval.exploration_step,
        coverage_steps: coverage_steps(&eval.coverage_steps),
        best_coverage_pct: eval.best.0,
        reachable_cells: eval.reachable_cells(),
        bytes_wire_total: Some(wire_total(plan, rec)),
        bytes_payload_total: eval.last.values().map(|l| l.t.bytes_sent).sum::<u64>()
            + earlier.iter().map(|l| l.bytes_sent).sum::<u64>(),
        traffic_shares_pct: traffic_shares(&by_type),
        bytes_by_type: by_type,
        splits_per_step_final: eval
            .last
            .iter()
            .map(|(r, l)| (r.to_string(), l.t.splits_per_step))
            .collect(),
        backlog_max_bytes,
        backlog_mean_bytes,
        approx_error_avg: approx_error_avg(eval),
        logs_held: logs_held(eval),
        collisions_robots: last.collisions_total,
        collisions_walls: last.blocked_total,
        fidelity: tally.fidelity(),
        distance_m: last.robots.iter().map(|r| r.distance_m).collect(),
        radio_decode_errors: eval.last.values().map(|l| l.t.decode_errors).sum(),
        reconnect: (&links.reconnects()).into(),
        awareness: tally.awareness(),
        comm_level_pct: tally.comm_level(),
        // Judgements of steps netem reported (the run's last step may have none).
        link_judgement: (links.last_step())
            .and_then(|reported| check_judgements(&eval.judged, links.up_by_step(), reported)),
        channel: links.channel_summary(),
        failed_processes: rec.failed.clone(),
        process_events: rec.sup.events.clone(),
        logs_held_by_others: held_by_others(rec)
            .iter()
            .map(|(o, (n, _))| (o.to_string(), *n))
            .collect(),
        logs_held_max: logs_held_max(rec),
        nodes_alive_at_end: alive_at_end(&last),
        lost_logs: lost_logs(rec, &alive_at_end(&last)),
        deterministic: false,
        nondeterministic: nondeterministic(plan, rec),
        run_digest: String::new(),
    }
}

/// The bytes on the wire. With step markers, up to the run's last step (what crossed while the
/// processes stopped depends on timing). Else netem's final counters when it wrote them (they
/// include that too), or the last per-step reports. A restarted netem wrote only its own life's
/// counters: then the reports, which span every life.
fn wire_total(plan: &Plan, rec: &Record) -> u64 {
    if plan.scenario.clock.marked() || rec.sup.life(Process::Netem) > 0 {
        rec.tables.links.wire_total()
    } else {
        link_totals_wire(&plan.dir.join("link_totals.csv"))
            .unwrap_or_else(|| rec.tables.links.wire_total())
    }
}

/// Per robot, how many records of each owner's log it held at its last report.
fn logs_held(eval: &Evaluator) -> BTreeMap<String, BTreeMap<String, u32>> {
    let held = |t: &Telemetry| t.logs.iter().map(|(o, n)| (o.to_string(), *n)).collect();
    eval.last
        .iter()
        .map(|(r, l)| (r.to_string(), held(&l.t)))
        .collect()
}

/// Per robot (its last life), the most of each owner's log it held at any step.
fn logs_held_max(rec: &Record) -> BTreeMap<String, BTreeMap<String, u32>> {
    let most = |r: RobotId, life: u16| {
        let most = rec.held_max.get(&(r, life)).into_iter().flatten();
        most.map(|(o, (n, _))| (o.to_string(), *n)).collect()
    };
    rec.eval
        .last
        .iter()
        .map(|(r, l)| (r.to_string(), most(*r, l.t.life)))
        .collect()
}

/// What made the run depend on more than its scenario (empty: nothing did).
fn nondeterministic(plan: &Plan, rec: &Record) -> Vec<String> {
    let mut why = Vec::new();
    match plan.scenario.clock.mode {
        ClockMode::Realtime => why.push("realtime clock: steps follow the wall clock".to_string()),
        ClockMode::Lockstep if !plan.scenario.clock.markers => why.push(
            "lockstep without step markers (clock.markers = false): robots take radio traffic as it arrives"
                .to_string(),
        ),
        ClockMode::Lockstep => {
            // Checked at start (netem refuses bad faults), so a table that does not parse here
            // is not one netem applies.
            if let Ok(faults) = netem::faults::parse_faults(&plan.scenario.faults) {
                for f in faults {
                    if let Some(reason) = f.fault.outside_plan() {
                        why.push(format!("step {}: fault outside the step plan: {reason}", f.step));
                    }
                }
            }
        }
    }
    for st in &rec.statuses {
        if !st.missed.is_empty() {
            why.push(format!(
                "step {}: the world went on without the commands of robots {:?} (its step wait ran out: clock.step_timeout_ms, docs/design.md §2.1)",
                st.step.saturating_sub(1),
                st.missed
            ));
        }
    }
    for (step, robot) in rec.late_reports() {
        why.push(format!(
            "step {step}: robot {robot}'s telemetry came after the world was two steps on"
        ));
    }
    if !rec.settled_in_time {
        why.push("the last step's reports did not all arrive".to_string());
    }
    for f in &rec.failed {
        why.push(format!("a process failed: {f}"));
    }
    for e in &rec.sup.events {
        why.push(format!(
            "step {}: {} {} ({}): process faults and restarts act on the wall clock",
            e.step, e.process, e.event, e.cause
        ));
    }
    why
}

/// The lives of robots that are not their robot's last report (they ended in a restart).
fn earlier_lives(rec: &Record) -> Vec<&super::follow::Life> {
    rec.lives
        .iter()
        .filter(|((robot, life), _)| rec.eval.last.get(robot).is_some_and(|l| l.t.life != *life))
        .map(|(_, l)| l)
        .collect()
}

/// The nodes (robots, then the base station) alive in `last`.
fn alive_at_end(last: &Status) -> Vec<RobotId> {
    last.robots
        .iter()
        .chain(&last.base)
        .filter(|r| r.alive)
        .map(|r| r.id)
        .collect()
}

/// Per owner: the most of its log a node other than its writer (in that life) held at any
/// step taken, (ops, encoded bytes).
fn held_by_others(rec: &Record) -> super::follow::Held {
    let mut out = super::follow::Held::new();
    for (&(node, life), held) in &rec.held_max {
        let own = log_owner(node, life);
        for (&owner, &(n, bytes)) in held.iter().filter(|(&o, _)| Some(o) != own) {
            let most = out.entry(owner).or_default();
            most.0 = most.0.max(n);
            most.1 = most.1.max(bytes);
        }
    }
    out
}

/// Per robot life that ended before the run (a restart followed, or the robot is dead at the
/// end): its own log against the most of it a node alive at the end holds.
fn lost_logs(rec: &Record, alive: &[RobotId]) -> Vec<LostLog> {
    // The final reports of the nodes alive at the end.
    let holders: Vec<&Telemetry> = rec
        .eval
        .last
        .iter()
        .filter(|(id, _)| alive.contains(id))
        .map(|(_, l)| &l.t)
        .collect();
    let others_held = held_by_others(rec);
    let mut out = Vec::new();
    for (&(robot, life), held) in &rec.held_max {
        let current = holders.iter().any(|t| t.robot == robot && t.life == life);
        let Some(owner) = log_owner(robot, life).filter(|_| !current) else {
            continue;
        };
        let (own_ops, own_bytes) = held.get(&owner).copied().unwrap_or_default();
        let holder = holders
            .iter()
            .filter_map(|t| {
                let ops = t.logs.iter().find(|h| h.0 == owner)?.1;
                let bytes = t.log_bytes.iter().find(|h| h.0 == owner).map(|h| h.1);
                Some((ops, bytes))
            })
            .max_by_key(|h| h.0);
        let (ops_held, bytes_held) = holder.unwrap_or((0, Some(0)));
        // Its last report may predate ops it sent before it died: others may hold more.
        let others = others_held.get(&owner).copied().unwrap_or_default();
        let ops_written = own_ops.max(others.0);
        let bytes_written = own_bytes.max(others.1);
        out.push(LostLog {
            robot,
            life,
            ops_written,
            ops_held,
            ops_lost: ops_written.saturating_sub(ops_held),
            bytes_written,
            bytes_lost: bytes_written
                .zip(bytes_held.or(Some(0)))
                .map(|(w, h)| w.saturating_sub(h)),
        });
    }
    out
}

/// Mean over the robots of their own e_avg (polygon exchange only).
fn approx_error_avg(eval: &Evaluator) -> Option<f64> {
    let e: Vec<f64> = eval
        .last
        .values()
        .filter_map(|l| l.t.approx_error_avg)
        .collect();
    (!e.is_empty()).then(|| e.iter().sum::<f64>() / e.len() as f64)
}

/// `truth.png` with every trajectory, `robot_<id>.png` per robot, every robot's final
/// planning grid and G_s as maps (`grids/robot_<id>_{planning,own}.pgm`, each with its
/// map_server YAML), and the map the team has to learn (`grids/truth_reachable.pgm` and `.yaml`,
/// [`crate::score::floor`]).
pub fn write_pictures(
    dir: &Path,
    run_truth: (&Grid, proto::geom::MapInfo),
    reachable: &Grid,
    rec: &Record,
    progress: &mut Progress,
) -> anyhow::Result<()> {
    let (truth, info) = run_truth;
    let trajectories = &rec.trajectories();
    let mut truth_pic = Picture::of_grid(truth, info);
    for (i, t) in trajectories.iter().enumerate() {
        truth_pic.path(t, robot_colour(i));
        if let Some(&p) = t.first() {
            truth_pic.marker(p, robot_colour(i));
        }
    }
    truth_pic.save(&dir.join("truth.png"))?;
    for (id, l) in &rec.eval.last {
        let mut pic = Picture::of_grid(&l.planning.grid, info);
        let i = usize::from(*id);
        if let Some(t) = trajectories.get(i) {
            pic.path(t, robot_colour(i));
            if let Some(&p) = t.last() {
                pic.marker(p, robot_colour(i));
            }
        }
        pic.save(&dir.join(format!("robot_{id}.png")))?;
    }
    let grids = dir.join("grids");
    std::fs::create_dir_all(&grids).context("creating grids/")?;
    write_map(
        &grids.join("truth_reachable.pgm"),
        &crate::score::floor::reachable_map(truth, reachable),
        info,
    )?;
    for (id, l) in &rec.eval.last {
        // The evaluator keeps only grids of the truth's size; a robot's own grid whose last
        // report could not be taken is reported, not written.
        write_map(
            &grids.join(format!("robot_{id}_planning.pgm")),
            &l.planning.grid,
            info,
        )?;
        let own = match &l.own {
            (own, None) => write_map(&grids.join(format!("robot_{id}_own.pgm")), &own.grid, info),
            (_, Some(e)) => Err(anyhow::anyhow!("{e}")),
        };
        if let Err(e) = own {
            progress.event(&format!(
                "swarm run: robot {id}'s own grid is not written: {e:#}"
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::run::tables::RowTally;
    use crate::rundir::summary::{AwarenessSummary, CommLevel};
    use crate::rundir::tables::MetricsRow;

    fn row(step: u32, robot: u16, coverage_pct: f64, shared: f64, since: u32) -> MetricsRow {
        MetricsRow {
            step,
            robot,
            coverage_pct,
            shared_pct: (robot != 2).then_some(shared),
            steps_since_base: (robot != 2).then_some(since),
            // The union of the step's robots: here each step's largest robot coverage.
            team_pct: (robot != 2).then_some(if step == 0 { 10.0 } else { 30.0 }),
            ..MetricsRow::default()
        }
    }

    /// The summary's tally of `rows`, robots `0..base` and base station `base`.
    fn tally(rows: &[MetricsRow], base: RobotId) -> RowTally {
        let mut t = RowTally::new(base, Some(base));
        for r in rows {
            t.add(r);
        }
        t
    }

    #[test]
    fn awareness_takes_the_base_station_s_last_coverage_and_step_means_of_the_robots() {
        // Robots 0 and 1, base station 2; step 1 lacks robot 1's report.
        let rows = [
            row(0, 0, 10.0, 100.0, 0),
            row(0, 1, 10.0, 50.0, 0),
            row(0, 2, 20.0, 0.0, 0),
            row(1, 0, 30.0, 80.0, 6),
            row(1, 2, 40.0, 0.0, 0),
        ];
        let a = tally(&rows, 2).awareness().expect("a base station");
        assert_eq!(
            a,
            AwarenessSummary {
                base_known_pct: Some(40.0),
                base_known_pct_mean: Some(30.0),
                shared_pct_mean: Some(77.5),
                steps_since_base_mean: Some(3.0),
                steps_since_base_max: Some(6),
                team_pct_mean: Some(20.0),
            }
        );
        assert_eq!(tally(&[], 2).awareness(), Some(AwarenessSummary::default()));
    }

    #[test]
    fn the_communication_level_is_summed_up_over_steps() {
        let at = |step, robot, pct: Option<f64>| MetricsRow {
            step,
            robot,
            comm_level_pct: pct,
            ..MetricsRow::default()
        };
        let rows = [
            at(0, 0, Some(100.0)),
            at(0, 1, Some(100.0)),
            at(1, 0, Some(50.0)),
            at(1, 2, None),
            at(2, 1, Some(0.0)),
        ];
        assert_eq!(
            tally(&rows, 2).comm_level(),
            Some(CommLevel {
                min: 0.0,
                mean: 50.0
            })
        );
        assert_eq!(tally(&[at(0, 2, None)], 2).comm_level(), None);
    }
}
