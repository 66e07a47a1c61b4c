//! Why the bridge's ROS 2 output could not start, or a sample not go out.

use ros2_client::Name;

use isochron_dds::DdsError;

/// Why ROS 2 output could not start.
#[derive(Debug, thiserror::Error)]
pub enum RosError {
    /// A topic name ROS 2 does not accept.
    #[error("invalid ROS 2 topic name '{name}': {detail}")]
    TopicName {
        /// The name.
        name: String,
        /// What is wrong.
        detail: String,
    },
    /// DDS could not be set up (ports, interfaces).
    #[error(transparent)]
    Dds(#[from] DdsError),
    /// Zenoh output could not be set up (its configuration, its session).
    #[error(transparent)]
    Zenoh(#[from] isochron_zenoh::ZenohError),
}

impl isochron_exit::Classify for RosError {
    /// DDS did not start (ports, interfaces, a name it refused): the network side
    /// is unavailable; a Zenoh configuration Zenoh refuses is permanent.
    fn exit_code(&self) -> i32 {
        match self {
            RosError::Zenoh(e) => isochron_exit::Classify::exit_code(e),
            _ => isochron_exit::UNAVAILABLE,
        }
    }
}

/// A sample could not be published (the text is what DDS or Zenoh said).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{detail}")]
pub struct PublishError {
    /// What DDS or Zenoh said.
    pub detail: String,
}

/// Parses a topic name (`/a/b` absolute, `a/b` relative to the node's namespace `/`).
pub fn topic_name(name: &str) -> Result<Name, RosError> {
    Name::parse(name).map_err(|e| RosError::TopicName {
        name: name.to_string(),
        detail: format!("{e}"),
    })
}
