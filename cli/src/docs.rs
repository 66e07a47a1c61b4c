//! Man pages and shell completions of `isochron`, made from its clap definition
//! ([`crate::command`]), and the man pages of the service binaries
//! (`isochron-capture.8`, …, from [`isochron_runtime::service::command`]), by
//! `cargo xtask docs` (through the `isochron-docs` example).

use std::path::{Path, PathBuf};

use clap_complete::Shell;
use isochron_runtime::topology::StageKind;

/// Writes `out/man/isochron.1` and one `isochron-<subcommand>.1` per subcommand
/// (nested ones too, e.g. `isochron-store-export.1`), one page per service binary
/// in section 8 (`isochron-capture.8`, …), and `out/completions/` for bash, zsh and fish.
/// Returns the files written.
pub fn write(out: &Path) -> std::io::Result<Vec<PathBuf>> {
    let mut command = crate::command();
    command.build();
    let man = out.join("man");
    std::fs::create_dir_all(&man)?;
    let mut written = Vec::new();
    man_pages(&command, &man, "1", &mut written)?;
    // Section 8, as daemons: `isochron-costmap.8` (the service) beside
    // `isochron-costmap.1` (`isochron costmap`).
    for stage in StageKind::EVERY {
        let mut service = isochron_runtime::service::command(stage);
        service.build();
        man_pages(&service, &man, "8", &mut written)?;
    }
    let completions = out.join("completions");
    std::fs::create_dir_all(&completions)?;
    for shell in [Shell::Bash, Shell::Zsh, Shell::Fish] {
        written.push(clap_complete::generate_to(
            shell,
            &mut command,
            "isochron",
            &completions,
        )?);
    }
    Ok(written)
}

/// Writes the page of the built `command` and of each of its subcommands into
/// `dir`, each named by its display name and manual `section`
/// (`isochron-store-export.1`).
fn man_pages(
    command: &clap::Command,
    dir: &Path,
    section: &str,
    written: &mut Vec<PathBuf>,
) -> std::io::Result<()> {
    let name = command.get_display_name().unwrap_or(command.get_name());
    let mut text = Vec::new();
    clap_mangen::Man::new(command.clone())
        .section(section.to_string())
        .render(&mut text)?;
    let path = dir.join(format!("{name}.{section}"));
    std::fs::write(&path, text)?;
    written.push(path);
    for sub in command.get_subcommands().filter(|s| s.get_name() != "help") {
        man_pages(sub, dir, section, written)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    #[test]
    fn every_command_has_a_page_and_completions() {
        let dir = tempfile::tempdir().unwrap();
        let written = super::write(dir.path()).unwrap();
        let man = dir.path().join("man");
        for page in [
            "isochron.1",
            "isochron-up.1",
            "isochron-store-info.1",
            "isochron-plan-now.1",
            "isochron-costmap.1",
            "isochron-capture.8",
            "isochron-costmap.8",
            "isochron-exporter.8",
        ] {
            let text = std::fs::read_to_string(man.join(page)).unwrap();
            assert!(text.starts_with(".ie") || text.contains(".TH"), "{page}");
        }
        let info = std::fs::read_to_string(man.join("isochron-store-info.1")).unwrap();
        assert!(info.contains("json"), "store info documents --json");
        let gate = std::fs::read_to_string(man.join("isochron-gate.8")).unwrap();
        assert!(
            gate.contains("camera") && gate.contains("detector"),
            "{gate}"
        );
        let link = std::fs::read_to_string(man.join("isochron-link.8")).unwrap();
        assert!(
            link.contains("config") && !link.contains("\\-\\-camera"),
            "{link}"
        );
        let bash = std::fs::read_to_string(dir.path().join("completions/isochron.bash")).unwrap();
        assert!(bash.contains("replay") && bash.contains("--speed"));
        assert!(dir.path().join("completions/_isochron").is_file());
        assert!(dir.path().join("completions/isochron.fish").is_file());
        assert_eq!(
            written.len(),
            std::fs::read_dir(&man).unwrap().count() + 3,
            "every file is reported"
        );
    }
}
