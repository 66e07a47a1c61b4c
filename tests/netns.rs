//! Network namespaces for the tests of several boxes: two namespaces joined by a
//! veth pair, and processes started inside them.

use std::path::Path;
use std::process::Command;

use crate::Proc;

/// Runs `ip args`; its status and stderr.
pub fn ip(args: &[&str]) -> (bool, String) {
    match Command::new("ip").args(args).output() {
        Ok(o) => (
            o.status.success(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        ),
        Err(e) => (false, e.to_string()),
    }
}

/// Two network namespaces joined by a veth pair — `10.77.<subnet>.1/24` in the
/// first, `.2/24` in the second, loopback up and a 224.0.0.0/4 route on each side
/// for DDS multicast discovery — deleted on drop.
pub struct NetnsPair {
    /// The namespaces.
    pub names: [String; 2],
    /// Their veth ends, in the same order.
    pub veths: [String; 2],
    /// Their addresses, in the same order.
    pub addrs: [String; 2],
}

impl NetnsPair {
    /// Makes the pair, named after `tag` (unique per test; short: interface names
    /// have at most 15 bytes). `None` where the kernel refuses `ip netns add` (not
    /// root), which is an error in CI (which runs as root).
    pub fn new(tag: &str, subnet: u8) -> Option<NetnsPair> {
        let names = [format!("isoa{tag}"), format!("isob{tag}")];
        let (ok, err) = ip(&["netns", "add", &names[0]]);
        if !ok {
            assert!(
                std::env::var("CI").is_err(),
                "`ip netns add` failed in CI (which runs as root): {err}"
            );
            eprintln!("skipped: `ip netns add` failed (needs root and iproute2): {err}");
            return None;
        }
        let pair = NetnsPair {
            veths: [format!("va{tag}"), format!("vb{tag}")],
            addrs: [format!("10.77.{subnet}.1"), format!("10.77.{subnet}.2")],
            names,
        };
        let [a, b] = &pair.names;
        let [va, vb] = &pair.veths;
        let mut steps: Vec<Vec<String>> = vec![
            vec!["netns".into(), "add".into(), b.clone()],
            vec![
                "link", "add", va, "netns", a, "type", "veth", "peer", "name", vb, "netns", b,
            ]
            .into_iter()
            .map(String::from)
            .collect(),
        ];
        for k in 0..2 {
            let (ns, veth) = (&pair.names[k], &pair.veths[k]);
            let addr = format!("{}/24", pair.addrs[k]);
            for step in [
                vec!["-n", ns, "addr", "add", &addr, "dev", veth],
                vec!["-n", ns, "link", "set", veth, "up"],
                vec!["-n", ns, "link", "set", "lo", "up"],
                vec!["-n", ns, "route", "add", "224.0.0.0/4", "dev", veth],
            ] {
                steps.push(step.into_iter().map(String::from).collect());
            }
        }
        for step in &steps {
            let args: Vec<&str> = step.iter().map(String::as_str).collect();
            let (ok, err) = ip(&args);
            assert!(ok, "ip {}: {err}", args.join(" "));
        }
        Some(pair)
    }

    /// Sets namespace `k`'s veth end up or down (both ends' carrier follows).
    pub fn set_link(&self, k: usize, up: bool) {
        let state = if up { "up" } else { "down" };
        let (ok, err) = ip(&["-n", &self.names[k], "link", "set", &self.veths[k], state]);
        assert!(ok, "setting {} {state}: {err}", self.veths[k]);
    }

    /// Bytes namespace `k`'s veth end has sent so far.
    pub fn tx_bytes(&self, k: usize) -> u64 {
        let out = Command::new("ip")
            .args(["netns", "exec", &self.names[k], "cat"])
            .arg(format!(
                "/sys/class/net/{}/statistics/tx_bytes",
                self.veths[k]
            ))
            .output()
            .expect("ip netns exec");
        String::from_utf8_lossy(&out.stdout)
            .trim()
            .parse()
            .unwrap_or(0)
    }

    /// `program args` started inside namespace `k`.
    pub fn spawn(&self, k: usize, program: &Path, args: &[impl AsRef<str>]) -> Proc {
        let mut all = vec![
            "netns".to_string(),
            "exec".into(),
            self.names[k].clone(),
            program.display().to_string(),
        ];
        all.extend(args.iter().map(|a| a.as_ref().to_string()));
        Proc::spawn(Path::new("ip"), &all)
    }
}

impl Drop for NetnsPair {
    fn drop(&mut self) {
        for n in &self.names {
            ip(&["netns", "del", n]);
        }
    }
}
