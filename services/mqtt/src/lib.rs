//! isochron-mqtt: the site's zone events and detections, as JSON, to an MQTT
//! broker (QoS 1), with a retained availability topic and a last will.
//!
//! [`message`] makes the topics and the JSON (the schema of docs/operating.md); [`outbox`] is
//! the bounded queue between the stage and the client, which drops the oldest
//! and counts it; [`client`] owns the broker connection on its own thread
//! (reconnecting with backoff), over TLS ([`tls`]) and with a user name and
//! password ([`login`]) when configured; [`stage`] is the service: a site-wide
//! stage on the shared runtime that reads every camera's streams into the
//! outbox.

pub mod client;
pub mod login;
pub mod message;
pub mod outbox;
pub mod stage;
pub mod tls;
