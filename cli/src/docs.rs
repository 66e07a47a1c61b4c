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
    for stage in StageKind::services() {
        let mut service = isochron_runtime::service::command(stage);
        service.build();
        man_pages(&service, &man, "8", &mut written)?;
    }
    written.push(write_services(out)?);
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

/// The file the installer reads the service binaries and units from.
pub const SERVICES_FILE: &str = "services.tsv";

/// Writes `out/services.tsv`: one line per stage with a service binary, from the
/// stage table — `binary`, `unit`, `per-camera` or `site`, and `always` or the
/// config section that turns it on — so `cargo xtask install` and `deb` list no
/// stage of their own.
fn write_services(out: &Path) -> std::io::Result<PathBuf> {
    use isochron_runtime::topology::Runs;
    let mut text = String::new();
    for stage in StageKind::services() {
        let spec = stage.spec();
        let scope = if spec.per_camera {
            "per-camera"
        } else {
            "site"
        };
        let when = match spec.runs {
            Runs::Always => "always",
            _ => spec.section,
        };
        let unit = spec.unit.unwrap_or("-");
        text += &format!("{}\t{unit}\t{scope}\t{when}\n", spec.binary);
    }
    let path = out.join(SERVICES_FILE);
    std::fs::write(&path, text)?;
    Ok(path)
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
            std::fs::read_dir(&man).unwrap().count() + 3 + 1,
            "every file is reported"
        );
        let services = std::fs::read_to_string(dir.path().join(super::SERVICES_FILE)).unwrap();
        assert!(
            services
                .starts_with("isochron-capture\tisochron-capture@.service\tper-camera\talways\n")
        );
        assert!(services.contains("isochron-link\tisochron-link.service\tsite\t[link]\n"));
    }
}
