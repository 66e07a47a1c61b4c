//! IPC benchmark: frames between two processes through iceoryx2 (as the services
//! send them: `frames` stream, loaned sample, event wake-up) and, in the same run,
//! through a Unix domain socket carrying the same bytes.
//!
//! Per size and transport: latency publish → receive (p50, p99) and CPU time per
//! frame of sender + receiver together: the sender's send calls (thread CPU time,
//! without the pacing sleeps) plus all the receiver's CPU time (wake-ups included).
//! Producing and consuming pixels is left out of both (the sender's frame is ready;
//! the receiver reads a few bytes), so the figures are the transport's own cost.
//!
//! Run: `cargo xtask bench ipc`. The binary re-executes itself as the receiver.
//! `--quick`: the same cases with [`QUICK_FRAMES`] frames each (a check that the
//! bench runs; its figures mean little).

use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::process::{Command, Stdio};
use std::time::Duration;

use iceoryx2::prelude::*;
use isochron_config::IpcConfig;
use isochron_runtime::ipc::{Frames, Ipc};
use isochron_runtime::names::ServiceNames;
use isochron_wire::{CameraId, FrameHeader, PixelFormat, Preamble, Stream};

/// Frames measured per case (after warm-up).
const FRAMES: usize = 1000;
const WARMUP: usize = 50;
/// Frames measured per case with `--quick`.
const QUICK_FRAMES: usize = 50;
/// Time between frames: the receiver is idle-waiting for each, as in the pipeline.
const INTERVAL: Duration = Duration::from_millis(3);
/// A receiver that sees no frame for this long reports what it has.
const RECEIVE_TIMEOUT: Duration = Duration::from_secs(5);

#[derive(Clone, Copy)]
struct Size {
    name: &'static str,
    width: u32,
    height: u32,
    format: PixelFormat,
}

const SIZES: [Size; 3] = [
    Size {
        name: "vga",
        width: 640,
        height: 480,
        format: PixelFormat::Gray8,
    },
    Size {
        name: "pets",
        width: 768,
        height: 576,
        format: PixelFormat::Gray8,
    },
    Size {
        name: "1080p",
        width: 1920,
        height: 1080,
        format: PixelFormat::Bgr8,
    },
];

impl Size {
    fn bytes(&self) -> usize {
        self.width as usize * self.height as usize * self.format.channels()
    }
    fn label(&self) -> String {
        format!(
            "{}x{} {}",
            self.width,
            self.height,
            match self.format {
                PixelFormat::Gray8 => "GRAY8",
                PixelFormat::Bgr8 => "BGR8",
            }
        )
    }
}

fn monotonic_ns() -> i64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: valid pointer to a timespec.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    ts.tv_sec * 1_000_000_000 + ts.tv_nsec
}

/// User + system CPU time of this process, microseconds.
fn cpu_us() -> f64 {
    // SAFETY: rusage is plain integers, for which all-zero bytes are a valid value.
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    // SAFETY: `ru` is a writable rusage and getrusage(2) writes only it.
    unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut ru) };
    let tv = |t: libc::timeval| t.tv_sec as f64 * 1e6 + t.tv_usec as f64;
    tv(ru.ru_utime) + tv(ru.ru_stime)
}

/// CPU time of the calling thread, microseconds: the sender times its send calls
/// with it, leaving out the pacing sleeps between frames.
fn thread_cpu_us() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: valid pointer to a timespec.
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
    ts.tv_sec as f64 * 1e6 + ts.tv_nsec as f64 / 1e3
}

fn ipc(prefix: &str, name: &str) -> Ipc {
    Ipc::new(name, ServiceNames::new(prefix), IpcConfig::default()).expect("iceoryx2 node")
}

/// What a receiver reports: latencies (µs) and its CPU time over the measured frames.
struct Received {
    latencies_us: Vec<f64>,
    cpu_us: f64,
}

fn quantile(v: &mut [f64], q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if let Some(i) = args.iter().position(|a| a == "--receiver") {
        receiver(
            &args[i + 1],
            &args[i + 2],
            args[i + 3].parse().expect("--receiver: a size index"),
            args[i + 4].parse().expect("--receiver: a frame count"),
        );
        return;
    }
    let quick = args.iter().any(|a| a == "--quick");
    let frames = if quick { QUICK_FRAMES } else { FRAMES };
    println!(
        "IPC benchmark: {frames} frames per case, one every {INTERVAL:?}, receiver waits for a wake-up"
    );
    println!(
        "{:<18} {:<9} {:>9} {:>9} {:>14} {:>5}",
        "frame", "transport", "p50 µs", "p99 µs", "CPU µs/frame", "lost"
    );
    let mut results = Vec::new();
    let mut lost_total = 0;
    for (s, size) in SIZES.iter().enumerate() {
        for transport in ["iceoryx2", "uds"] {
            let (mut lat, cpu, lost) = run_case(transport, s, frames);
            lost_total += lost;
            let (p50, p99) = (quantile(&mut lat, 0.5), quantile(&mut lat, 0.99));
            println!(
                "{:<18} {:<9} {:>9.1} {:>9.1} {:>14.1} {:>5}",
                size.label(),
                transport,
                p50,
                p99,
                cpu,
                lost
            );
            results.push((size.name, transport, p50, p99, cpu));
        }
    }
    let get = |size: &str, transport: &str| {
        results
            .iter()
            .find(|r| r.0 == size && r.1 == transport)
            .map(|r| (r.2, r.3, r.4))
            .expect("every size ran with every transport")
    };
    let (vga_p50, _, vga_cpu) = get("vga", "iceoryx2");
    let (hd_p50, hd_p99, hd_cpu) = get("1080p", "iceoryx2");
    let (_, _, uds_hd_cpu) = get("1080p", "uds");
    println!(
        "iceoryx2 CPU per frame VGA → 1080p: {vga_cpu:.1} → {hd_cpu:.1} µs ({:.2}×, {:.0}× the bytes); UDS needs {:.0}× the CPU at 1080p",
        hd_cpu / vga_cpu,
        SIZES[2].bytes() as f64 / SIZES[0].bytes() as f64,
        uds_hd_cpu / hd_cpu
    );
    println!(
        "{{\"bench\":\"ipc\",\"p50_us_vga\":{vga_p50:.1},\"p50_us_1080p\":{hd_p50:.1},\"p99_us_1080p\":{hd_p99:.1},\"cpu_us_per_frame_1080p\":{hd_cpu:.2},\"uds_cpu_over_iox2_1080p\":{:.1},\"lost_frames\":{lost_total}{}}}",
        uds_hd_cpu / hd_cpu,
        if quick { ",\"quick\":true" } else { "" }
    );
}

/// Runs one case of `frames` measured frames: spawns the receiver, sends, collects.
/// Returns latencies, CPU µs per frame of both processes together, and the frames
/// the receiver never got (dropped by a full queue under load).
fn run_case(transport: &str, size_index: usize, frames: usize) -> (Vec<f64>, f64, usize) {
    let size = SIZES[size_index];
    let tag = format!("ipcbench-{}-{transport}-{}", std::process::id(), size.name);
    let mut child = Command::new(std::env::current_exe().expect("this bench's path"))
        .args([
            "--receiver",
            transport,
            &tag,
            &size_index.to_string(),
            &frames.to_string(),
        ])
        .stdout(Stdio::piped())
        .spawn()
        .expect("receiver");
    let mut out = BufReader::new(child.stdout.take().expect("the receiver's piped stdout"));
    let mut line = String::new();
    let sender_cpu = match transport {
        "iceoryx2" => send_iceoryx2(&tag, size, frames, &mut out, &mut line),
        _ => send_uds(&tag, size, frames, &mut out, &mut line),
    };
    line.clear();
    out.read_line(&mut line).expect("receiver report");
    let _ = child.wait();
    let received: serde_json::Value = serde_json::from_str(&line).expect("receiver report");
    let latencies: Vec<f64> = received["latencies_us"]
        .as_array()
        .expect("receiver report: latencies_us")
        .iter()
        .map(|v| v.as_f64().expect("receiver report: a latency"))
        .collect();
    let lost = frames - latencies.len();
    let receiver_cpu = received["cpu_us"]
        .as_f64()
        .expect("receiver report: cpu_us");
    if std::env::var_os("IPC_BENCH_VERBOSE").is_some() {
        eprintln!(
            "{transport} {}: sender {:.1} µs/frame, receiver {:.1} µs/frame",
            size.label(),
            sender_cpu / frames as f64,
            receiver_cpu / latencies.len() as f64
        );
    }
    assert!(
        !latencies.is_empty(),
        "{transport} {}: the receiver got none of the measured frames",
        size.label()
    );
    let cpu = sender_cpu / frames as f64 + receiver_cpu / latencies.len() as f64;
    (latencies, cpu, lost)
}

fn receiver(transport: &str, tag: &str, size_index: usize, measured: usize) {
    let size = SIZES[size_index];
    let result = match transport {
        "iceoryx2" => {
            let ipc = ipc(tag, "ipcbench-receiver");
            let frames = ipc.subscriber::<Frames>("bench").expect("subscriber");
            // Woken as the services are: a WaitSet on the stream's event service.
            let waitset = WaitSetBuilder::new()
                .create::<ipc::Service>()
                .expect("waitset");
            let _guard = waitset.attach_notification(&frames).expect("attach");
            println!("ready");
            std::io::stdout().flush().expect("stdout");
            let mut latencies_us = Vec::with_capacity(measured);
            let (mut cpu0, mut checksum) = (0.0, 0u64);
            let last = (WARMUP + measured - 1) as u64;
            // Ends at the sender's last frame, or when frames stop coming: a sample the
            // subscriber's queue dropped under load is counted as lost, not waited for.
            let mut done = false;
            while !done {
                let mut woken = false;
                waitset
                    .wait_and_process_once_with_timeout(
                        |_| {
                            woken = true;
                            CallbackProgression::Continue
                        },
                        RECEIVE_TIMEOUT,
                    )
                    .expect("wait");
                frames.drain_wakeups();
                let mut got = false;
                while let Some(sample) = frames.receive().expect("receive") {
                    got = true;
                    let now = monotonic_ns();
                    let h = sample.user_header();
                    let pixels = sample.payload();
                    checksum += pixels[0] as u64 + pixels[pixels.len() - 1] as u64;
                    let index = h.source_index;
                    if index >= WARMUP as u64 {
                        if latencies_us.is_empty() {
                            cpu0 = cpu_us();
                        }
                        latencies_us.push((now - h.preamble.origin_wall_ns) as f64 / 1e3);
                    }
                    done |= index >= last;
                }
                if !woken && !got {
                    eprintln!("ipc bench receiver: no frame for {RECEIVE_TIMEOUT:?}, stopping");
                    break;
                }
            }
            std::hint::black_box(checksum);
            Received {
                latencies_us,
                cpu_us: cpu_us() - cpu0,
            }
        }
        _ => {
            let path = std::env::temp_dir().join(format!("{tag}.sock"));
            let _ = std::fs::remove_file(&path);
            let listener = UnixListener::bind(&path).expect("bind");
            println!("ready");
            std::io::stdout().flush().expect("stdout");
            let (mut stream, _) = listener.accept().expect("accept");
            let mut frame = vec![0u8; size.bytes() + 8];
            let mut latencies_us = Vec::with_capacity(measured);
            let mut cpu0 = 0.0;
            for n in 0..WARMUP + measured {
                stream.read_exact(&mut frame).expect("read");
                let now = monotonic_ns();
                if n == WARMUP {
                    cpu0 = cpu_us();
                }
                if n >= WARMUP {
                    let sent = i64::from_le_bytes(frame[..8].try_into().expect("8 bytes"));
                    latencies_us.push((now - sent) as f64 / 1e3);
                }
            }
            let _ = std::fs::remove_file(&path);
            Received {
                latencies_us,
                cpu_us: cpu_us() - cpu0,
            }
        }
    };
    println!(
        "{}",
        serde_json::json!({"latencies_us": result.latencies_us, "cpu_us": result.cpu_us})
    );
}

/// The sender's side of an iceoryx2 case: waits for the receiver's "ready" line,
/// sends `WARMUP + frames` frames at [`INTERVAL`]; returns the measured frames'
/// thread CPU time, µs.
fn send_iceoryx2(
    tag: &str,
    size: Size,
    frames: usize,
    out: &mut impl BufRead,
    line: &mut String,
) -> f64 {
    let ipc = ipc(tag, "ipcbench-sender");
    let mut publisher = ipc
        .publisher::<Frames>("bench", size.bytes())
        .expect("publisher");
    out.read_line(line).expect("receiver"); // "ready"
    while publisher.subscriber_count() == 0 {
        std::thread::sleep(Duration::from_millis(1));
    }
    let camera = CameraId::new("bench").expect("a valid camera id");
    paced(frames, |i| {
        let mut sample = publisher.loan(size.bytes()).expect("loan");
        let mut preamble = Preamble::new::<u8>(
            Stream::Frames,
            camera,
            publisher.next_sequence(),
            size.bytes(),
        );
        preamble.origin_wall_ns = monotonic_ns();
        *sample.user_header_mut() = FrameHeader {
            preamble,
            width: size.width,
            height: size.height,
            stride: size.width * size.format.channels() as u32,
            pixel_format: size.format as u32,
            source_index: i as u64,
        };
        // The pixels are already in place (a decoder writes them straight
        // into the loan); the transport moves none of them.
        // SAFETY: u8 has no invalid values; the benchmark never reads them.
        let sample = unsafe { sample.assume_init() };
        publisher.send(sample).expect("send");
    })
}

/// The sender's side of a Unix socket case, as [`send_iceoryx2`].
fn send_uds(
    tag: &str,
    size: Size,
    frames: usize,
    out: &mut impl BufRead,
    line: &mut String,
) -> f64 {
    let path = std::env::temp_dir().join(format!("{tag}.sock"));
    out.read_line(line).expect("receiver"); // "ready" once it listens
    let mut stream = UnixStream::connect(&path).expect("connect");
    let mut frame = vec![0u8; size.bytes() + 8];
    paced(frames, |_| {
        frame[..8].copy_from_slice(&monotonic_ns().to_le_bytes());
        stream.write_all(&frame).expect("write");
    })
}

/// Sends `WARMUP + frames` frames (`send(i)`) one every [`INTERVAL`]; returns the
/// thread CPU time the measured ones took, µs.
fn paced(frames: usize, mut send: impl FnMut(usize)) -> f64 {
    let mut cpu = 0.0;
    for i in 0..WARMUP + frames {
        let t0 = thread_cpu_us();
        send(i);
        if i >= WARMUP {
            cpu += thread_cpu_us() - t0;
        }
        std::thread::sleep(INTERVAL);
    }
    cpu
}
