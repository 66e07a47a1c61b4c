//! What the benchmarks share: a process's CPU time and memory, and their command
//! lines.

use std::time::Duration;

/// The resident set size of process `pid` (`VmRSS` in `/proc/<pid>/status`),
/// bytes; `None` once it has gone.
pub fn rss_bytes(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let kb: u64 = status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))?
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    Some(kb * 1024)
}

/// utime + stime of process `pid`, in clock ticks.
pub fn cpu_ticks(pid: u32) -> Option<u64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // The command (field 2) may hold spaces: count fields after its ')'.
    let rest = &stat[stat.rfind(')')? + 1..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    // Fields from 3 (state) on: utime is field 14, stime 15.
    let utime: u64 = fields.get(11)?.parse().ok()?;
    let stime: u64 = fields.get(12)?.parse().ok()?;
    Some(utime + stime)
}

/// Clock ticks per second.
pub fn clock_ticks_per_s() -> f64 {
    // SAFETY: sysconf has no preconditions.
    let ticks = unsafe { libc::sysconf(libc::_SC_CLK_TCK) };
    if ticks > 0 { ticks as f64 } else { 100.0 }
}

/// Reads a benchmark's command line into `(flag, value)` pairs in order: the
/// `valued` flags take a value (`--flag V` or `--flag=V`), the `bare` ones none
/// (`None`). `--help` or `-h` gives `usage` as the error, as does a missing
/// value; other arguments are ignored with a note naming `bench` (silently for
/// the `--bench` cargo passes).
pub fn bench_args(
    bench: &str,
    usage: &str,
    (bare, valued): (&[&str], &[&str]),
    args: impl IntoIterator<Item = String>,
) -> Result<Vec<(String, Option<String>)>, String> {
    let mut out = Vec::new();
    let mut args = args.into_iter();
    while let Some(arg) = args.next() {
        let (flag, inline) = match arg.split_once('=') {
            Some((f, v)) => (f.to_string(), Some(v.to_string())),
            None => (arg.clone(), None),
        };
        if flag == "--help" || flag == "-h" {
            return Err(usage.into());
        }
        if bare.contains(&flag.as_str()) {
            out.push((flag, None));
        } else if valued.contains(&flag.as_str()) {
            let value = inline
                .or_else(|| args.next())
                .ok_or_else(|| format!("{flag} needs a value\n{usage}"))?;
            out.push((flag, Some(value)));
        } else if flag != "--bench" {
            eprintln!("{bench}: ignoring unknown argument '{arg}'");
        }
    }
    Ok(out)
}

/// A benchmark's options, which `parse` reads from its command line (after the
/// program's name); on an error (or `--help`) prints it and exits with 2.
pub fn bench_options<T>(
    parse: impl FnOnce(std::iter::Skip<std::env::Args>) -> Result<T, String>,
) -> T {
    parse(std::env::args().skip(1)).unwrap_or_else(|e| {
        eprintln!("{e}");
        std::process::exit(2);
    })
}

/// The seconds (at least `min`) a benchmark option `flag` gives.
pub fn bench_secs(flag: &str, value: &str, min: f64) -> Result<Duration, String> {
    value
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite() && *v >= min)
        .and_then(|v| Duration::try_from_secs_f64(v).ok())
        .ok_or_else(|| format!("{flag}: expected seconds ≥ {min}, found '{value}'"))
}

/// The count (at least 1) a benchmark option `flag` gives.
pub fn bench_count(flag: &str, value: &str) -> Result<usize, String> {
    value
        .parse::<usize>()
        .ok()
        .filter(|v| *v >= 1)
        .ok_or_else(|| format!("{flag}: expected a whole number ≥ 1, found '{value}'"))
}
