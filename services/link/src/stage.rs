//! The link's stage: exported cameras' `activity` → DDS, DDS → imported cameras'
//! `activity` in this box's iceoryx2 services.
//!
//! * Export: every wake takes the newest sample of each woken camera (latest-only:
//!   an older one still waiting is counted as dropped) and publishes it.
//! * Import: every tick ([`POLL`]) takes what DDS received for each imported camera
//!   and publishes it with the remote header unchanged — sequence, capture and
//!   origin times — so the bridge, `tap` and `status` see a local camera and
//!   measure gaps and latency end to end. A link that stops receiving writes
//!   nothing: the bridge's `costmap.stale_s` then turns the camera's cells unknown.

use std::net::IpAddr;
use std::time::{Duration, Instant};

use ros2_client::dds::{Publisher, Subscription};

use isochron_shared::config::LoadedConfig;
use isochron_shared::ipc::{Activity as ActivityStream, Ipc};
use isochron_shared::service::Fatal;
use isochron_shared::stage::{Context, Input, Output, Stage, Woken};
use isochron_shared::topology::StageKind;
use isochron_shared::wire::CameraId;

use crate::dds::{LinkDds, domain_id};
use crate::msgs::Activity;

/// How often the DDS readers are polled: a second's activity waits at most this
/// long on the importing box.
pub const POLL: Duration = Duration::from_millis(20);

/// Messages one reader yields per tick (more wait for the next tick).
const TAKE_PER_TICK: usize = 16;

/// One exported camera: what was sent.
struct Export {
    camera: String,
    writer: Publisher<Activity>,
    messages: u64,
    bytes: u64,
    errors: u64,
}

/// One imported camera.
struct Import<'ipc> {
    camera: String,
    id: CameraId,
    reader: Subscription<Activity>,
    output: Output<'ipc, ActivityStream>,
    messages: u64,
    last: Option<Instant>,
}

/// The link of one box.
pub struct LinkStage<'ipc> {
    box_id: String,
    exports: Vec<Export>,
    imports: Vec<Import<'ipc>>,
    started: Instant,
    _dds: LinkDds,
}

impl<'ipc> LinkStage<'ipc> {
    /// Joins DDS as `[link]` says and opens the exported cameras' activity inputs
    /// (in `link.export` order).
    pub fn open(
        ipc: &'ipc Ipc,
        loaded: &LoadedConfig,
    ) -> Result<(Self, Vec<Input<ActivityStream>>), Fatal> {
        let link = &loaded.config.link;
        if !link.is_enabled() {
            tracing::warn!(
                "[link] exports and imports no camera: nothing to do (see link.export, link.import)"
            );
        }
        let domain = domain_id(link.ros_domain_id)?;
        let interfaces: Vec<IpAddr> = link
            .dds_interfaces
            .iter()
            .filter_map(|a| a.parse().ok())
            .collect();
        let mut dds = LinkDds::start(domain, &interfaces, &link.box_id, link.namespace())?;
        let mut exports = Vec::new();
        let mut inputs = Vec::new();
        for camera in &link.export {
            exports.push(Export {
                camera: camera.clone(),
                writer: dds.publisher(camera)?,
                messages: 0,
                bytes: 0,
                errors: 0,
            });
            inputs.push(Input::open(ipc, camera)?);
        }
        let mut imports = Vec::new();
        for camera in &link.import {
            imports.push(Import {
                camera: camera.clone(),
                id: CameraId::new(camera).unwrap_or_default(),
                reader: dds.subscription(camera)?,
                output: Output::new(ipc, camera),
                messages: 0,
                last: None,
            });
        }
        tracing::info!(
            box_id = %link.box_id,
            domain,
            "link up: exports [{}] imports [{}] under {}",
            link.export.join(", "),
            link.import.join(", "),
            link.namespace()
        );
        Ok((
            LinkStage {
                box_id: link.box_id.clone(),
                exports,
                imports,
                started: Instant::now(),
                _dds: dds,
            },
            inputs,
        ))
    }
}

impl Stage for LinkStage<'_> {
    type Inputs = Vec<Input<ActivityStream>>;
    const KIND: StageKind = StageKind::Link;

    fn on_wake(
        &mut self,
        inputs: &Self::Inputs,
        woken: &Woken,
        cx: &mut Context,
    ) -> Result<(), Fatal> {
        for (k, (input, export)) in inputs.iter().zip(&mut self.exports).enumerate() {
            if !woken.contains(k) {
                continue;
            }
            let mut newest = None;
            while let Some(sample) = input.next(cx) {
                if sample.is_end_of_stream() {
                    continue;
                }
                if newest.is_some() {
                    cx.health.dropped(1);
                }
                newest = Some(Activity::from_sample(
                    &self.box_id,
                    sample.header(),
                    sample.payload(),
                ));
            }
            let Some(msg) = newest else { continue };
            let (bytes, origin) = (msg.cdr_len() as u64, msg.origin_wall_ns);
            match export.writer.publish(msg) {
                Ok(()) => {
                    export.messages += 1;
                    export.bytes += bytes;
                    cx.health.sent(None, origin);
                }
                Err(e) => {
                    export.errors += 1;
                    cx.warnings.warn("publish", || {
                        format!("publishing {}'s activity: {e:?}", export.camera)
                    });
                }
            }
        }
        Ok(())
    }

    fn on_tick(&mut self, cx: &mut Context) -> Result<(), Fatal> {
        for import in &mut self.imports {
            for _ in 0..TAKE_PER_TICK {
                let msg = match import.reader.take() {
                    Ok(Some((msg, _info))) => msg,
                    Ok(None) => break,
                    Err(e) => {
                        cx.health.rejected();
                        cx.warnings.warn("read", || {
                            format!("an unreadable message of {}: {e:?}", import.camera)
                        });
                        continue;
                    }
                };
                let arrived = Instant::now();
                cx.health.received(msg.sequence);
                let (header, blocks) = match msg.to_sample(&import.id) {
                    Ok(s) => s,
                    Err(e) => {
                        cx.health.rejected();
                        cx.warnings.warn("header", || {
                            format!(
                                "rejected activity of {} from box '{}': {e}",
                                import.camera, msg.box_id
                            )
                        });
                        continue;
                    }
                };
                import.output.send_copy(header, &blocks)?;
                import.messages += 1;
                import.last = Some(arrived);
                cx.health
                    .sent(Some(arrived), header.preamble.origin_wall_ns);
            }
        }
        Ok(())
    }

    fn on_stop(&mut self, _cx: &mut Context) -> Result<(), Fatal> {
        let secs = self.started.elapsed().as_secs_f64().max(1e-3);
        for e in &self.exports {
            tracing::info!(
                "exported {}: {} messages, {} bytes of CDR ({} B/message), {:.0} B/s over {secs:.1} s",
                e.camera,
                e.messages,
                e.bytes,
                e.bytes / e.messages.max(1),
                e.bytes as f64 / secs
            );
        }
        Ok(())
    }

    fn timer(&self) -> Duration {
        if self.imports.is_empty() {
            isochron_shared::stage::IDLE_TICK
        } else {
            POLL
        }
    }

    fn detail(&self) -> String {
        let now = Instant::now();
        let exported: Vec<String> = self
            .exports
            .iter()
            .map(|e| {
                format!(
                    "{}:msgs={},bytes={},errors={}",
                    e.camera, e.messages, e.bytes, e.errors
                )
            })
            .collect();
        let imported: Vec<String> = self
            .imports
            .iter()
            .map(|i| {
                let age = i.last.map_or("never".to_string(), |t| {
                    format!("{:.1}s", now.duration_since(t).as_secs_f64())
                });
                format!("{}:msgs={},last={age}", i.camera, i.messages)
            })
            .collect();
        format!(
            "box={} export=[{}] import=[{}]",
            self.box_id,
            exported.join(" "),
            imported.join(" ")
        )
    }
}
