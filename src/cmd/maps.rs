//! `swarm maps`: the worlds `world.map` can name — the real maps the binary carries (size,
//! resolution, where each comes from and under which licence) and the generated worlds.

use std::fmt::Write as _;

use proto::scenario::GeneratedWorld;
use world_server::shipped::SHIPPED;

/// What `swarm maps` prints.
pub fn listing() -> anyhow::Result<String> {
    let mut out = String::from(
        "Maps this binary carries (world.map = NAME; a file NAME.yaml in the scenario's \
         directory, its maps/ or ./configs/maps wins):\n",
    );
    for m in &SHIPPED {
        let map = m.load()?;
        let (w, h, res) = (map.info.width, map.info.height, map.info.resolution_m);
        let p = m.provenance();
        writeln!(
            out,
            "\n{}  {w} × {h} cells, {:.1} × {:.1} m at {res} m a cell\n    {}\n    source: {}\n    licence: {}",
            m.name,
            f64::from(w) * res,
            f64::from(h) * res,
            p.description,
            p.source,
            p.licence
        )?;
    }
    out.push_str(
        "\nGenerated worlds (world.map = NAME; made from the seed, world.width_m × \
         world.height_m):\n\n",
    );
    for g in GeneratedWorld::ALL {
        writeln!(out, "{:<14} {}", g.name(), g.about())?;
    }
    Ok(out)
}

/// `swarm maps`: prints the listing.
pub fn command() -> anyhow::Result<std::process::ExitCode> {
    print!("{}", listing()?);
    Ok(std::process::ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_carried_map_and_generated_world_is_listed_with_its_facts() {
        let text = listing().unwrap_or_else(|e| panic!("{e:#}"));
        for m in &SHIPPED {
            assert!(
                text.contains(&format!("\n{}  ", m.name)),
                "{}:\n{text}",
                m.name
            );
        }
        for g in GeneratedWorld::ALL {
            assert!(text.contains(g.name()) && text.contains(g.about()), "{g:?}");
        }
        // intel_lab: 579 × 581 cells at 0.048 m; its licence as SOURCES.md has it.
        assert!(
            text.contains("intel_lab  579 × 581 cells, 27.8 × 27.9 m at 0.048 m"),
            "{text}"
        );
        assert!(
            text.contains("licence: MIT-0"),
            "aws_small_house's licence:\n{text}"
        );
    }
}
