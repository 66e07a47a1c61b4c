//! The sink's stage: every camera's `events` and `detections` in (lossy
//! subscribers: a slow broker never holds the gate back), JSON messages into the
//! [`Outbox`](crate::outbox::Outbox), which the [client](crate::client) thread
//! publishes. On every tick it reports what the broker acknowledged (as `sent`,
//! with the time from receiving the gate's sample to the broker's PUBACK as the stage
//! latency) and what the full queue dropped. An event record that cannot be a
//! real zone event (it ends before it starts) is rejected and counted, never
//! published.

use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use isochron_config::LoadedConfig;
use isochron_exit::{self as exit, Fatal};
use isochron_runtime::counters::{Counters, mqtt};
use isochron_runtime::health::LatencyWindow;
use isochron_runtime::ipc::{Detections, Events, Ipc};
use isochron_runtime::service::ServiceContext;
use isochron_runtime::stage::{self, Context, Input, Stage};
use isochron_runtime::topology::StageKind;

use crate::client::{self, Settings, Shared};
use crate::message::{Topics, detections_json, event_json, implausible_event};
use crate::outbox::{MAX_PACKET_BYTES, Message, packet_len};
use crate::{login, tls};

/// Runs the sink on `ctx`'s site until it is asked to stop. Without `[mqtt]` it
/// says so and exits (nothing leaves the box unless configured).
pub fn run(ctx: ServiceContext) -> Result<(), Fatal> {
    let Some((mut sink, inputs)) = MqttStage::open(&ctx.ipc, &ctx.config)? else {
        tracing::info!(
            "no [mqtt] section in {}: nothing to publish",
            ctx.config.path.display()
        );
        return Ok(());
    };
    stage::run(&ctx.ipc, "", &mut sink, &inputs)
}

/// The sink's inputs: every camera's events, then every camera's detections.
pub type MqttInputs = (Vec<Input<Events>>, Vec<Input<Detections>>);

/// The MQTT sink of one site.
pub struct MqttStage {
    shared: Arc<Shared>,
    client: Option<JoinHandle<()>>,
    cameras: Vec<String>,
    topics: Topics,
    broker: String,
    messages: u64,
    events_rejected: u64,
    dropped_reported: u64,
    /// Recent PUBACK latencies, ms, for the status's quantiles.
    ack_ms: LatencyWindow,
}

impl MqttStage {
    /// The sink of `loaded`'s site and its inputs, or `None` without `[mqtt]`. A
    /// bad `[mqtt]` key, or a TLS or password file that cannot be read, is a
    /// configuration error (one line: file, line, key, expected).
    pub fn open(ipc: &Ipc, loaded: &LoadedConfig) -> Result<Option<(Self, MqttInputs)>, Fatal> {
        let Some(config) = loaded.mqtt()? else {
            return Ok(None);
        };
        let located = |e| Fatal::from(loaded.locate(e));
        let broker = config.broker_addr().map_err(located)?;
        let base = loaded.base_dir();
        let tls_config = tls::client_config(config, &base).map_err(located)?;
        let credentials = login::login(config, &base).map_err(located)?;
        let site_name = &loaded.config.site.name;
        let topics = Topics::new(&config.topic_prefix, config.site_level(site_name));
        let cameras: Vec<String> = loaded.config.cameras.iter().map(|c| c.id.clone()).collect();
        let mut events = Vec::new();
        let mut detections = Vec::new();
        for camera in &cameras {
            events.push(Input::open(ipc, camera)?);
            detections.push(Input::open(ipc, camera)?);
        }
        let shared = Shared::new(config.queue_len);
        let settings = Settings {
            host: broker.host,
            port: broker.port,
            url: config.broker.clone(),
            client_id: config.client_id(site_name),
            status_topic: topics.status(),
            keepalive: Duration::from_secs(config.keepalive_s),
            reconnect_max: isochron_config::clock::saturating_secs(config.reconnect_max_s),
            tls: tls_config,
            login: credentials,
        };
        let client = client::spawn(settings, shared.clone()).map_err(|e| {
            Fatal::new(
                exit::UNAVAILABLE,
                format!("starting the MQTT client thread: {e}"),
            )
        })?;
        tracing::info!(
            "publishing the zone events and detections of {} cameras to {} under {}/",
            cameras.len(),
            config.broker,
            topics
                .events("<camera>")
                .trim_end_matches("/<camera>/events")
        );
        let sink = MqttStage {
            shared,
            client: Some(client),
            cameras,
            topics,
            broker: config.broker.clone(),
            messages: 0,
            events_rejected: 0,
            dropped_reported: 0,
            ack_ms: LatencyWindow::default(),
        };
        Ok(Some((sink, (events, detections))))
    }

    fn queue(&mut self, topic: String, json: serde_json::Value, arrived: Instant, origin: i64) {
        self.messages += 1;
        let message = Message {
            topic,
            payload: json.to_string().into_bytes(),
            arrived,
            origin_wall_ns: origin,
        };
        let bytes = packet_len(&message);
        let topic = message.topic.clone();
        if !self.shared.outbox().push(message) {
            tracing::warn!(
                "a message of {bytes} bytes on {topic} is larger than the {MAX_PACKET_BYTES} bytes an MQTT packet of the sink may be: dropped"
            );
        }
    }

    /// Counts what the broker acknowledged and the queue dropped since the last
    /// call.
    fn account(&mut self, cx: &mut Context) {
        let (acked, dropped) = {
            let mut outbox = self.shared.outbox();
            (outbox.take_acked(), outbox.dropped())
        };
        for m in acked {
            self.ack_ms.push(m.arrived.elapsed().as_secs_f32() * 1e3);
            cx.health.sent(Some(m.arrived), m.origin_wall_ns);
        }
        if dropped > self.dropped_reported {
            cx.health.dropped(dropped - self.dropped_reported);
            self.dropped_reported = dropped;
        }
    }
}

impl Stage for MqttStage {
    type Inputs = MqttInputs;
    const KIND: StageKind = StageKind::Mqtt;

    fn on_wake(
        &mut self,
        (events, detections): &MqttInputs,
        cx: &mut Context,
    ) -> Result<(), Fatal> {
        let before = self.messages;
        for (k, input) in events.iter().enumerate() {
            while let Some(sample) = input.next(cx) {
                if sample.is_end_of_stream() {
                    continue;
                }
                let h = sample.header();
                if let Some(why) = implausible_event(h) {
                    self.events_rejected += 1;
                    cx.health.rejected();
                    let camera = &self.cameras[k];
                    cx.warnings.warn("implausible-event", || {
                        format!(
                            "camera {camera}: event {} (sequence {}) rejected, not published: {why}",
                            h.event_id, h.preamble.sequence
                        )
                    });
                    continue;
                }
                let json = event_json(&self.cameras[k], h, sample.payload());
                let topic = self.topics.events(&self.cameras[k]);
                self.queue(topic, json, Instant::now(), h.preamble.origin_wall_ns);
            }
        }
        for (k, input) in detections.iter().enumerate() {
            while let Some(sample) = input.next(cx) {
                // Only frames where the detector found someone.
                if sample.is_end_of_stream() || sample.payload().is_empty() {
                    continue;
                }
                let h = sample.header();
                let json = detections_json(&self.cameras[k], h, sample.payload());
                let topic = self.topics.detections(&self.cameras[k]);
                self.queue(topic, json, Instant::now(), h.preamble.origin_wall_ns);
            }
        }
        if self.messages > before {
            self.shared.wake();
        }
        Ok(())
    }

    fn on_tick(&mut self, cx: &mut Context) -> Result<(), Fatal> {
        self.account(cx);
        Ok(())
    }

    fn timer(&self) -> Duration {
        Duration::from_millis(100)
    }

    fn take_inputs_on_stop(&self) -> bool {
        true
    }

    fn on_stop(&mut self, cx: &mut Context) -> Result<(), Fatal> {
        self.shared.stop();
        if let Some(client) = self.client.take() {
            // The client flushes for at most client::FLUSH (plus a connection
            // attempt under way), then counts what is left as dropped.
            if client.join().is_err() {
                tracing::error!("the MQTT client thread panicked");
            }
        }
        self.account(cx);
        Ok(())
    }

    fn counters(&self, c: &mut Counters) {
        let (queued, dropped) = {
            let outbox = self.shared.outbox();
            (outbox.len(), outbox.dropped())
        };
        c.set(mqtt::CONNECTED, self.shared.connected());
        c.set(mqtt::MESSAGES, self.messages);
        c.set(mqtt::QUEUED, queued);
        c.set(mqtt::QUEUE_DROPPED, dropped);
        c.set(mqtt::RECONNECTS, self.shared.reconnects());
        c.set(mqtt::REFUSED, self.shared.refused());
        c.set(mqtt::TLS_FAILURES, self.shared.tls_failures());
        c.set(mqtt::EVENTS_REJECTED, self.events_rejected);
        c.set(mqtt::ACK_P50, self.ack_ms.quantile(0.5));
        c.set(mqtt::ACK_P99, self.ack_ms.quantile(0.99));
    }

    fn info(&self) -> String {
        format!("broker={}", self.broker)
    }
}
