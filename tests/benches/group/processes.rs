//! The running group: its service processes, their memory, shared memory, and
//! interrupts that stop them.

use std::fmt::Write as _;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use isochron_tests::{Proc, TestSite, cpu_ticks};

use crate::{COSTMAP, Mode, STAGES, STOP_TIMEOUT};

/// One service process of the group.
pub(crate) struct Member {
    /// Index in [`STAGES`].
    pub(crate) stage: usize,
    /// Its cameras, comma-separated (empty for the bridge).
    pub(crate) cameras: String,
    pub(crate) proc: Proc,
}

impl Member {
    pub(crate) fn describe(&self) -> String {
        if self.cameras.is_empty() {
            STAGES[self.stage].binary().to_string()
        } else {
            format!("{} --camera {}", STAGES[self.stage].binary(), self.cameras)
        }
    }
}

/// The running group: every service process of one site.
pub(crate) struct Group {
    pub(crate) members: Vec<Member>,
}

impl Group {
    /// Starts the bridge, then for each per-camera stage from the last to capture
    /// (consumers before producers) one process per `per_process` cameras — of
    /// the stages `mode` runs.
    pub(crate) fn spawn(
        site: &TestSite,
        mode: Mode,
        cameras: &[String],
        per_process: usize,
    ) -> Group {
        let mut members = Vec::new();
        if mode.stages().contains(&COSTMAP) {
            members.push(Member {
                stage: COSTMAP,
                cameras: String::new(),
                proc: site.spawn("isochron-costmap", &[]),
            });
        }
        for stage in (0..COSTMAP).rev().filter(|s| mode.stages().contains(s)) {
            for chunk in cameras.chunks(per_process) {
                let list = chunk.join(",");
                let binary = STAGES[stage].binary();
                let proc = site.spawn(binary, &["--camera", &list]);
                members.push(Member {
                    stage,
                    cameras: list,
                    proc,
                });
            }
        }
        Group { members }
    }

    /// Why the group is broken, if a process exited.
    pub(crate) fn dead(&mut self) -> Option<String> {
        let mut dead = Vec::new();
        for m in &mut self.members {
            if let Some(status) = m.proc.wait(Duration::ZERO) {
                let stderr = m.proc.stderr();
                let last = stderr.lines().rev().find(|l| !l.trim().is_empty());
                dead.push(format!(
                    "{} exited ({status}){}",
                    m.describe(),
                    last.map(|l| format!(": {}", l.trim())).unwrap_or_default()
                ));
            }
        }
        if dead.is_empty() {
            return None;
        }
        let more = dead.len() - 1;
        let mut reason = dead.swap_remove(0);
        if more > 0 {
            let _ = write!(reason, " (and {more} more processes)");
        }
        Some(reason)
    }

    /// CPU time so far of every process, in clock ticks (`None` once it is gone).
    pub(crate) fn cpu_ticks(&self) -> Vec<Option<u64>> {
        self.members
            .iter()
            .map(|m| cpu_ticks(m.proc.pid()))
            .collect()
    }

    /// Private memory of the processes of each stage ([`STAGES`]), bytes.
    pub(crate) fn private_bytes(&self) -> [u64; 5] {
        let mut per_stage = [0; 5];
        for m in &self.members {
            per_stage[m.stage] += private_bytes(m.proc.pid()).unwrap_or(0);
        }
        per_stage
    }

    /// Stops every process: SIGTERM to all at once, up to [`STOP_TIMEOUT`] for them
    /// to clean up, SIGKILL for the rest. Says so when stopping was slow.
    pub(crate) fn stop(mut self) {
        let t0 = Instant::now();
        for m in &self.members {
            m.proc.signal(libc::SIGTERM);
        }
        // Exit time of each member, polled together so the slowest is known.
        let mut stopped: Vec<Option<Duration>> = vec![None; self.members.len()];
        while stopped.iter().any(Option::is_none) && t0.elapsed() < STOP_TIMEOUT {
            for (m, t) in self.members.iter_mut().zip(&mut stopped) {
                if t.is_none() && m.proc.wait(Duration::ZERO).is_some() {
                    *t = Some(t0.elapsed());
                }
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        let mut killed = Vec::new();
        for (m, t) in self.members.iter_mut().zip(&stopped) {
            if t.is_none() {
                m.proc.signal(libc::SIGKILL);
                let _ = m.proc.wait(Duration::from_secs(2));
                killed.push(m.describe());
            }
        }
        if let Some(first) = killed.first() {
            eprintln!(
                "group: {} of {} processes had not stopped {:.0} s after SIGTERM and were killed, e.g. {first}",
                killed.len(),
                self.members.len(),
                STOP_TIMEOUT.as_secs_f64(),
            );
        } else if let Some((m, t)) = self
            .members
            .iter()
            .zip(&stopped)
            .filter_map(|(m, t)| Some((m, (*t)?)))
            .max_by_key(|(_, t)| *t)
            && t > Duration::from_secs(5)
        {
            eprintln!(
                "group: the processes took up to {:.1} s to stop after SIGTERM (slowest: {})",
                t.as_secs_f64(),
                m.describe()
            );
        }
    }
}

/// Private_Clean + Private_Dirty of every mapping of `pid` except `/dev/shm` files
/// (those are counted once, in [`ShmUsage`]), bytes.
pub(crate) fn private_bytes(pid: u32) -> Option<u64> {
    let smaps = std::fs::read_to_string(format!("/proc/{pid}/smaps")).ok()?;
    let mut total_kb = 0u64;
    let mut in_shm = false;
    for line in smaps.lines() {
        let mut words = line.split_whitespace();
        let Some(first) = words.next() else { continue };
        if !first.ends_with(':') {
            // A mapping's header: `start-end perms offset dev inode [path]`.
            in_shm = line.contains(" /dev/shm/");
            continue;
        }
        if !in_shm && (first == "Private_Clean:" || first == "Private_Dirty:") {
            total_kb += words
                .next()
                .and_then(|v| v.parse::<u64>().ok())
                .unwrap_or(0);
        }
    }
    Some(total_kb * 1024)
}

/// What the files in `/dev/shm` take, bytes.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct ShmUsage {
    /// Memory actually in use (allocated pages).
    pub(crate) used: u64,
    /// The files' sizes: what is mapped, the most they can come to use.
    pub(crate) mapped: u64,
}

impl ShmUsage {
    /// The usage now.
    pub(crate) fn now() -> ShmUsage {
        fn walk(dir: &Path, total: &mut ShmUsage) {
            use std::os::unix::fs::MetadataExt;
            let Ok(entries) = std::fs::read_dir(dir) else {
                return;
            };
            for entry in entries.flatten() {
                match entry.metadata() {
                    Ok(m) if m.is_dir() => walk(&entry.path(), total),
                    Ok(m) => {
                        total.used += m.blocks() * 512;
                        total.mapped += m.size();
                    }
                    Err(_) => {}
                }
            }
        }
        let mut total = ShmUsage::default();
        walk(Path::new("/dev/shm"), &mut total);
        total
    }

    /// The growth since `before`.
    pub(crate) fn since(self, before: ShmUsage) -> ShmUsage {
        ShmUsage {
            used: self.used.saturating_sub(before.used),
            mapped: self.mapped.saturating_sub(before.mapped),
        }
    }
}

/// Set by SIGINT or SIGTERM: the bench stops the running group and finishes.
pub(crate) static INTERRUPTED: AtomicBool = AtomicBool::new(false);

extern "C" fn on_interrupt(_signal: libc::c_int) {
    INTERRUPTED.store(true, Ordering::Relaxed);
}

/// Catches SIGINT and SIGTERM, so that an interrupted bench still stops its
/// processes (they are not killed with it).
pub(crate) fn catch_interrupts() {
    for signal in [libc::SIGINT, libc::SIGTERM] {
        // SAFETY: the handler only stores to an atomic.
        unsafe {
            libc::signal(signal, on_interrupt as *const () as libc::sighandler_t);
        }
    }
}

pub(crate) fn interrupted() -> bool {
    INTERRUPTED.load(Ordering::Relaxed)
}
