//! One topic of the bridge on every transport that is on: DDS always, Zenoh
//! when configured.

use serde::Serialize;

use isochron_dds::RosNode;
use isochron_zenoh::{RosPublisher, RosZenoh};

use crate::dds::{self, Offered};
use crate::error::{PublishError, RosError};
use crate::spec::TopicSpec;
use crate::zenoh::put;

/// A topic's publisher: a sample published goes out on DDS and, when it is on,
/// on Zenoh.
pub struct Publisher<M: Serialize> {
    dds: ros2_client::Publisher<M>,
    /// What the DDS writer offers, for its matched readers.
    offered: Offered,
    zenoh: Option<RosPublisher>,
}

impl<M: Serialize> Publisher<M> {
    /// The publisher of `spec`'s topic `name` on `ros`'s node and, if given,
    /// `zenoh`'s.
    pub(crate) fn start(
        spec: &TopicSpec<M>,
        name: &str,
        ros: &mut RosNode,
        zenoh: Option<&RosZenoh>,
    ) -> Result<Self, RosError> {
        let (dds, offered) = dds::publisher(ros, spec, name)?;
        let zenoh = match zenoh {
            Some(z) => Some(z.publisher(name, &spec.ty, spec.qos)?),
            None => None,
        };
        Ok(Publisher {
            dds,
            offered,
            zenoh,
        })
    }

    /// Publishes `message` on every transport; the first error, DDS's before
    /// Zenoh's, if one failed (the others still got it).
    pub fn publish(&self, message: M) -> Result<(), PublishError> {
        let zenoh = self.zenoh.as_ref().map(|z| put(z, &message));
        // What a failed write says, without the sample it carries back (a whole
        // grid in a log line).
        self.dds.publish(message).map_err(|e| PublishError {
            detail: e.to_string(),
        })?;
        zenoh.unwrap_or(Ok(()))
    }

    /// The remote DDS readers matched with this topic's writer on `ros`.
    pub(crate) fn dds_readers(&self, ros: &RosNode) -> usize {
        self.offered.readers(ros)
    }
}
