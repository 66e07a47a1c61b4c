//! The workload: the site of N cameras, and the churn video they replay.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use isochron_tests::{repo_root, vtest};
use opencv::core::{Mat, Size};
use opencv::prelude::*;
use opencv::videoio;

use crate::{BACKGROUND_SAMPLES, BUSY_S, CYCLE_FRAMES, FLOOR_POINTS, FPS, Mode, QUIET_S};

/// Camera ids `cam001`, `cam002`, ….
pub(crate) fn camera_ids(n: usize) -> Vec<String> {
    (1..=n).map(|i| format!("cam{i:03}")).collect()
}

/// A DDS domain unlikely to collide with tests running at the same time.
pub(crate) fn ros_domain() -> u16 {
    1 + (std::process::id() % 229) as u16
}

/// The site config (after `[site]`) for `cameras` in `mode`, replaying the churn
/// `video`: camera *i* of N starts *i*/N of a cycle in; the detector's settings
/// are the defaults but for `cpu_share`, when given, and `enabled` with
/// `no_detector`.
///
/// The quiet part is a cut to the busy part's median, so a camera that started
/// in the busy part sees blocks differ from everything it learned, arriving with
/// the cut's motion: the presence band rightly holds them present until they are
/// absorbed. A short `absorb_s` lets the events end inside the window (what is
/// measured is the end record's latency, not how long presence held the event);
/// the band still runs on every camera, so its cost is in the figures.
pub(crate) fn site_body(
    mode: Mode,
    cameras: &[String],
    video: &Path,
    (cpu_share, no_detector): (Option<f64>, bool),
) -> String {
    let source = serde_json::to_string(&video.display().to_string()).unwrap_or_default();
    let mut share = cpu_share.map_or(String::new(), |s| format!("cpu_share = {s}\n"));
    if no_detector {
        share.push_str("enabled = false\n");
    }
    let mut body = format!(
        "[presence]\nabsorb_s = 5.0\n\n\
         [gate.detector]\n{share}\n\
         [costmap]\norigin_x_m = -22.0\norigin_y_m = -18.0\nresolution_m = 0.1\n\
         width_cells = 320\nheight_cells = 300\nframe_id = \"map\"\n\
         topic = \"/isochron/bench_costmap\"\nros_domain_id = {}\n\
         dds_interfaces = [\"127.0.0.1\"]\n",
        ros_domain()
    );
    for (i, id) in cameras.iter().enumerate() {
        let start_frame = (2 * i as u64 + 1) * u64::from(CYCLE_FRAMES) / (2 * cameras.len() as u64);
        let _ = write!(
            body,
            "\n[[camera]]\nid = \"{id}\"\nsource = {source}\nfps = {FPS:.1}\nloop = true\n\
             start_frame = {start_frame}\n"
        );
        if mode == Mode::Predecoded {
            let _ = writeln!(body, "preload_frames = {CYCLE_FRAMES}");
        }
        let _ = writeln!(body, "{FLOOR_POINTS}");
    }
    body
}

/// The churn video (see the module doc): made from vtest on first use, kept in
/// `target/bench-data/`. Returns its path and the codec it was written with.
pub(crate) fn churn_video() -> Result<(PathBuf, String), String> {
    let dir = repo_root().join("target/bench-data");
    let path = dir.join(format!("churn-busy{BUSY_S}s-quiet{QUIET_S}s.avi"));
    let codec_of = |path: &Path| -> Result<String, String> {
        let cap = videoio::VideoCapture::from_file(path.display().to_string(), videoio::CAP_ANY)
            .map_err(|e| format!("{}: {e}", path.display()))?;
        let fourcc = cap.get(videoio::CAP_PROP_FOURCC).unwrap_or(0.0) as u32;
        Ok(fourcc_name(fourcc))
    };
    if path.exists() {
        return Ok((path.clone(), codec_of(&path)?));
    }
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let t0 = Instant::now();
    let source = vtest();
    let err = |e: opencv::Error| format!("making the churn video from {}: {e}", source.display());
    let mut cap = videoio::VideoCapture::from_file(source.display().to_string(), videoio::CAP_ANY)
        .map_err(err)?;
    let fourcc = cap.get(videoio::CAP_PROP_FOURCC).map_err(err)? as i32;
    let mut frames: Vec<Mat> = Vec::new();
    let mut frame = Mat::default();
    while cap.read(&mut frame).map_err(err)? && !frame.empty() {
        frames.push(frame.try_clone().map_err(err)?);
    }
    let busy = (BUSY_S * FPS as u32) as usize;
    if frames.len() < busy.max(BACKGROUND_SAMPLES) {
        return Err(format!(
            "{}: {} frames, the churn video needs {}",
            source.display(),
            frames.len(),
            busy.max(BACKGROUND_SAMPLES)
        ));
    }
    let background = median_frame(&frames, BACKGROUND_SAMPLES).map_err(err)?;
    let size: Size = frames[0].size().map_err(err)?;
    let partial = dir.join(format!("churn-partial-{}.avi", std::process::id()));
    // vtest's codec if this OpenCV can write it, else Motion JPEG (always built in).
    let mjpg = videoio::VideoWriter::fourcc('M', 'J', 'P', 'G').map_err(err)?;
    let mut writer = None;
    for code in [fourcc, mjpg] {
        let w = videoio::VideoWriter::new(partial.display().to_string(), code, FPS, size, true)
            .map_err(err)?;
        if w.is_opened().map_err(err)? {
            writer = Some(w);
            break;
        }
    }
    let mut writer = writer.ok_or_else(|| format!("OpenCV cannot write {}", partial.display()))?;
    for f in &frames[..busy] {
        writer.write(f).map_err(err)?;
    }
    for _ in 0..QUIET_S * FPS as u32 {
        writer.write(&background).map_err(err)?;
    }
    writer.release().map_err(err)?;
    std::fs::rename(&partial, &path).map_err(|e| format!("{}: {e}", path.display()))?;
    let codec = codec_of(&path)?;
    eprintln!(
        "group: made {} ({codec}, {CYCLE_FRAMES} frames) in {:.1} s",
        path.display(),
        t0.elapsed().as_secs_f64()
    );
    Ok((path, codec))
}

/// A fourcc code as its four characters.
pub(crate) fn fourcc_name(code: u32) -> String {
    code.to_le_bytes()
        .iter()
        .map(|&b| if b.is_ascii_graphic() { b as char } else { '?' })
        .collect()
}

/// The per-pixel (per-byte) median of `samples` frames spread evenly over `frames`.
pub(crate) fn median_frame(frames: &[Mat], samples: usize) -> opencv::Result<Mat> {
    let picked: Vec<&[u8]> = (0..samples)
        .map(|k| frames[k * frames.len() / samples].data_bytes())
        .collect::<opencv::Result<_>>()?;
    let mut out = frames[0].try_clone()?;
    let bytes = out.data_bytes_mut()?;
    let mut column = Vec::with_capacity(samples);
    for (i, byte) in bytes.iter_mut().enumerate() {
        column.clear();
        column.extend(picked.iter().map(|f| f[i]));
        let mid = column.len() / 2;
        *byte = *column.select_nth_unstable(mid).1;
    }
    Ok(out)
}
