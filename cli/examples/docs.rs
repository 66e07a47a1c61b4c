//! `isochron-docs [OUT_DIR]`: writes the man pages and shell completions of
//! `isochron` into OUT_DIR (default `target/docs`); `cargo xtask docs` runs it.

fn main() -> std::io::Result<()> {
    let out = std::env::args_os()
        .nth(1)
        .map(std::path::PathBuf::from)
        .unwrap_or_else(|| "target/docs".into());
    let written = isochron_cli::docs::write(&out)?;
    println!("{} files in {}", written.len(), out.display());
    Ok(())
}
