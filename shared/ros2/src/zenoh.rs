//! The Zenoh transport (`[costmap.zenoh]`, off by default): the bridge's topics
//! and planning services in rmw_zenoh's format, beside DDS, so that a robot
//! whose ROS 2 middleware is rmw_zenoh sees the same topics, with the same QoS,
//! and calls the same services ([`isochron_zenoh`] has the names and bytes).
//!
//! Samples are the DDS samples' CDR ([`crate::msgs`]) after the encapsulation
//! header. A request's client is the GID of its attachment; a request without
//! one cannot be answered (rmw_zenoh's client matches a reply to its request by
//! it) and is counted only. Requests beyond what the queryable holds between two
//! passes of the loop ([`INBOX`]) are dropped and counted.
//!
//! The route server's `DynamicEdges` is called as rmw_zenoh's clients call a
//! service ([`ZenohCaller`]): a query with the attachment, the reply matched by
//! its sequence number.

use std::fmt;

use byteorder::LittleEndian;
use rustdds::serialization::to_vec;
use serde::Serialize;

use isochron_zenoh::names::GID_LEN;
use isochron_zenoh::{Request, RosClient, RosPublisher, RosService, RosZenoh, ZenohError};

use crate::error::PublishError;
use crate::msgs::DynamicEdges;
use crate::plan::{Body, Endpoint, Service, Taken, WarningKinds};
use crate::route_server::{CALL_TIMEOUT, Caller};
use crate::spec::{RosType, ServiceSpec};

/// Requests a service's Zenoh queryable holds between two passes of the loop.
pub const INBOX: usize = 256;

/// Publishes `message` on `publisher`.
pub(crate) fn put<T: Serialize>(publisher: &RosPublisher, message: &T) -> Result<(), PublishError> {
    let cdr = to_vec::<T, LittleEndian>(message).map_err(|e| PublishError {
        detail: format!("Zenoh: encoding: {e}"),
    })?;
    publisher.put(&cdr).map_err(|e| PublishError {
        detail: e.to_string(),
    })
}

/// An rmw_zenoh client's GID: the client whose lane a request joins.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Gid(pub [u8; GID_LEN]);

impl fmt::Display for Gid {
    /// In hexadecimal.
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        self.0.iter().try_for_each(|b| write!(f, "{b:02x}"))
    }
}

/// One planning service on Zenoh: its queryable.
pub struct ZenohService {
    service: RosService,
    /// Requests the queryable had dropped when last looked at.
    inbox_dropped: u64,
}

impl ZenohService {
    /// The service `spec` named `name` on `zenoh`'s node.
    pub(crate) fn start(
        zenoh: &RosZenoh,
        spec: &ServiceSpec,
        name: &str,
    ) -> Result<Service<ZenohService>, ZenohError> {
        let endpoint = ZenohService {
            service: zenoh.service(name, &spec.ty, INBOX)?,
            inbox_dropped: 0,
        };
        Ok(Service::new(spec.kind, format!("{name} (Zenoh)"), endpoint))
    }
}

impl Endpoint for ZenohService {
    type Client = Gid;
    type Reply = Request;
    const WARNINGS: WarningKinds = WarningKinds {
        unreadable: "zenoh plan request unreadable",
        unanswerable: "zenoh plan request unanswerable",
        dropped: "zenoh plan request dropped",
        reply_failed: "zenoh plan reply failed",
    };

    /// What the queryable received, and how many it dropped since.
    fn take(&mut self) -> Vec<Taken<Gid, Request>> {
        let mut taken = Vec::new();
        let inbox_dropped = self.service.dropped();
        if inbox_dropped > self.inbox_dropped {
            taken.push(Taken::Lost {
                n: inbox_dropped - self.inbox_dropped,
                client: None,
                why: "the Zenoh inbox was full",
            });
            self.inbox_dropped = inbox_dropped;
        }
        while let Some(request) = self.service.take() {
            let Some(attachment) = request.attachment else {
                // Dropping the request ends its query.
                taken.push(Taken::Unanswerable(
                    "no rmw_zenoh attachment, by which a reply is matched to its request".into(),
                ));
                continue;
            };
            let body = read(&request.payload());
            taken.push(Taken::Request {
                client: Gid(attachment.gid),
                reply: request,
                body,
            });
        }
        taken
    }

    /// Replies with rmw_zenoh's attachment.
    fn reply(&self, request: Request, cdr: &[u8]) -> Result<(), String> {
        self.service.reply(request, cdr).map_err(|e| e.to_string())
    }
}

/// The bridge's Zenoh client of one `DynamicEdges` service: the server is the
/// first whose liveliness token is alive; a call is a query.
pub struct ZenohCaller {
    client: RosClient,
}

impl ZenohCaller {
    /// The client of the service `name` of `ty` on `zenoh`'s node; a relative
    /// name is in the root namespace, where the route server resolves it.
    pub fn start(zenoh: &RosZenoh, name: &str, ty: &RosType) -> Result<ZenohCaller, ZenohError> {
        let absolute = if name.starts_with('/') {
            name.to_string()
        } else {
            format!("/{name}")
        };
        Ok(ZenohCaller {
            client: zenoh.client(&absolute, ty, CALL_TIMEOUT)?,
        })
    }
}

impl Caller for ZenohCaller {
    /// The server's token, hashed as rmw_zenoh hashes a GID.
    fn server(&mut self) -> Option<u128> {
        self.client
            .server()
            .map(|token| u128::from_le_bytes(isochron_zenoh::names::gid(&token)))
    }

    fn call(&mut self, request: &DynamicEdges) -> Result<u64, String> {
        let cdr = to_vec::<_, LittleEndian>(request).map_err(|e| format!("encoding: {e}"))?;
        self.client
            .call(&cdr)
            .map(|sequence| sequence as u64)
            .map_err(|e| e.to_string())
    }

    /// `success` is the reply's first byte (a CDR `bool`).
    fn answers(&mut self) -> Vec<(u64, bool)> {
        self.client
            .replies()
            .into_iter()
            .filter_map(|(sequence, fields)| Some((sequence as u64, *fields.first()? != 0)))
            .collect()
    }
}

/// The fields of the request `payload`: after the encapsulation header, plain
/// CDR of its byte order.
fn read(payload: &[u8]) -> Result<Body, String> {
    let Some((header, body)) = payload.split_first_chunk::<4>() else {
        return Err(format!(
            "a request of {} bytes: shorter than its encapsulation header",
            payload.len()
        ));
    };
    let big_endian = match header[..2] {
        [0x00, 0x01] => false,
        [0x00, 0x00] => true,
        _ => {
            return Err(format!(
                "a request encoded as {:02x}{:02x}: expected plain CDR (XCDR1), as rmw_zenoh sends",
                header[0], header[1]
            ));
        }
    };
    Ok(Body {
        cdr: body.to_vec(),
        big_endian,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requests_need_their_encapsulation_header() {
        assert!(read(&[0, 1]).unwrap_err().contains("shorter"));
        let err = read(&[0, 7, 0, 0, 1, 2, 3, 4]).unwrap_err();
        assert!(err.contains("expected plain CDR"), "{err}");
        let le = read(&[0, 1, 0, 0, 1, 2]).unwrap();
        assert_eq!((le.cdr, le.big_endian), (vec![1, 2], false));
        assert!(read(&[0, 0, 0, 0]).unwrap().big_endian);
    }

    #[test]
    fn gids_read_in_hexadecimal() {
        let mut gid = [0u8; GID_LEN];
        gid[0] = 0xab;
        gid[15] = 0x01;
        assert_eq!(Gid(gid).to_string(), "ab000000000000000000000000000001");
    }
}
