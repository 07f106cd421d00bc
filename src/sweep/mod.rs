//! `swarm sweep`: an experiment file's grid of runs × seeds, run a few at a time and resumable
//! (here, or as a Slurm job array), then its results, report and plots.

/// `[[curve]]` of a sweep report: a `metrics.csv` column over the steps, averaged over seeds.
pub mod curve;
/// Charts (SVG and PNG) of a sweep's results.
pub mod plot;
/// A sweep's report: plots, tables, report.md.
pub mod report;
/// A sweep's results: runs.csv and results.csv (means, std, 95 % intervals).
pub mod results;
/// Running the grid: resumable, a few runs at a time.
pub mod runner;
/// A sweep as a Slurm job array: submitting, waiting, the tasks.
pub mod slurm;
