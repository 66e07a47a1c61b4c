//! `isochron`: the command-line tool people use to run and watch a site (the
//! commands live in the library, `cli/src/lib.rs`).

fn main() -> std::process::ExitCode {
    isochron_cli::main()
}
