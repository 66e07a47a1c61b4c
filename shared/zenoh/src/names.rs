//! rmw_zenoh's names: data key expressions, liveliness tokens, their QoS field,
//! entity GIDs and the attachment every sample and request carries.
//!
//! Read from rmw_zenoh_cpp (`liveliness_utils.cpp`, `attachment_helpers.cpp`,
//! `rmw_publisher_data.cpp`, `rmw_service_data.cpp`; Jazzy and later):
//!
//! * data: `<domain>/<name without its outer slashes>/<dds type>/<type hash>`, e.g.
//!   `0/isochron/activity_costmap/nav_msgs::msg::dds_::OccupancyGrid_/RIHS01_8d34…`;
//! * liveliness: `@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<kind>/<enclave>/
//!   <namespace>/<node>[/<name>/<dds type>/<type hash>/<qos>]`, each name with its
//!   `/` written `%`;
//! * an entity's GID: XXH3-128 of its liveliness key expression, low 64 bits then
//!   high 64 bits, little-endian;
//! * attachment: sequence number (i64), source timestamp (i64, ns), GID (16 bytes
//!   after its length, 16), in zenoh-ext's serialization (little-endian).

/// The liveliness admin space of rmw_zenoh.
pub const ADMIN_SPACE: &str = "@ros2_lv";
/// The depth rmw_zenoh's QoS field leaves out (`RMW_ZENOH_DEFAULT_HISTORY_DEPTH`).
const RMW_ZENOH_DEFAULT_DEPTH: usize = 42;
/// Bytes of an rmw GID (`RMW_GID_STORAGE_SIZE` since Jazzy).
pub const GID_LEN: usize = 16;
/// Bytes of an attachment: two i64, the GID's length (one byte) and the GID.
pub const ATTACHMENT_LEN: usize = 8 + 8 + 1 + GID_LEN;

/// A ROS 2 type as rmw_zenoh names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RosType {
    /// The DDS name, e.g. `nav_msgs::msg::dds_::OccupancyGrid_` (a service's without
    /// `Request_`/`Response_`: `isochron_msgs::srv::dds_::PlanNow_`).
    pub dds_name: &'static str,
    /// The type description hash, `RIHS01_<64 hex digits>`.
    pub hash: &'static str,
}

/// What kind of entity a liveliness token announces.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EntityKind {
    /// A node (`NN`).
    Node,
    /// A publisher (`MP`).
    Publisher,
    /// A service server (`SS`).
    Service,
    /// A service client (`SC`).
    Client,
}

impl EntityKind {
    fn code(self) -> &'static str {
        match self {
            EntityKind::Node => "NN",
            EntityKind::Publisher => "MP",
            EntityKind::Service => "SS",
            EntityKind::Client => "SC",
        }
    }
}

/// The QoS a topic is offered with, as far as rmw_zenoh encodes it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Qos {
    /// Reliable (else best effort).
    pub reliable: bool,
    /// Transient-local: late joiners get the last `depth` samples.
    pub transient_local: bool,
    /// Keep last this many.
    pub depth: usize,
}

impl Qos {
    /// ROS 2's default for services: reliable, volatile, keep last 10.
    pub const SERVICES: Qos = Qos {
        reliable: true,
        transient_local: false,
        depth: 10,
    };

    /// The QoS field of a liveliness token: only what differs from rmw_zenoh's
    /// default (reliable, volatile, keep last 42, durations infinite) is written, as
    /// `reliability:durability:history,depth:deadline s,ns:lifespan s,ns:liveliness,s,ns`
    /// with rmw's enum values (reliable 1, best effort 2; transient-local 1,
    /// volatile 2; keep last 1).
    pub fn token_field(&self) -> String {
        let reliability = if self.reliable { "" } else { "2" };
        let durability = if self.transient_local { "1" } else { "" };
        let depth = if self.depth == RMW_ZENOH_DEFAULT_DEPTH {
            String::new()
        } else {
            self.depth.to_string()
        };
        format!("{reliability}:{durability}:,{depth}:,:,:,,")
    }
}

/// `/` written as `%`, as rmw_zenoh mangles names inside a key expression.
pub fn mangle(name: &str) -> String {
    name.replace('/', "%")
}

/// The data key expression of `name` (a topic or a service) of `ty` in `domain`.
pub fn data_keyexpr(domain: u16, name: &str, ty: &RosType) -> String {
    let name = name.trim_matches('/');
    format!("{domain}/{name}/{}/{}", ty.dds_name, ty.hash)
}

/// A node as its liveliness tokens name it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeInfo {
    /// ROS domain.
    pub domain: u16,
    /// The Zenoh session's id, as Zenoh prints it.
    pub zid: String,
    /// The node's id within the session.
    pub node_id: u32,
    /// Namespace, e.g. `/isochron`.
    pub namespace: String,
    /// Name, e.g. `costmap_bridge`.
    pub name: String,
    /// SROS2 enclave, `/` when none.
    pub enclave: String,
}

/// A liveliness token's key expression: the node's (`entity` `None`) or one of its
/// entities' (`(id, kind, name, type, qos)`).
pub fn liveliness_keyexpr(
    node: &NodeInfo,
    entity: Option<(u32, EntityKind, &str, &RosType, Qos)>,
) -> String {
    let (id, kind) = entity.map_or((node.node_id, EntityKind::Node), |e| (e.0, e.1));
    let mut key = format!(
        "{ADMIN_SPACE}/{}/{}/{}/{id}/{}/{}/{}/{}",
        node.domain,
        node.zid,
        node.node_id,
        kind.code(),
        mangle(&node.enclave),
        mangle(&node.namespace),
        mangle(&node.name),
    );
    if let Some((_, _, name, ty, qos)) = entity {
        key.push_str(&format!(
            "/{}/{}/{}/{}",
            mangle(name),
            mangle(ty.dds_name),
            mangle(ty.hash),
            qos.token_field()
        ));
    }
    key
}

/// The key expression that matches the liveliness token of every server of the
/// service `name` of `ty` in `domain`, whatever its session, node and QoS.
pub fn servers_keyexpr(domain: u16, name: &str, ty: &RosType) -> String {
    format!(
        "{ADMIN_SPACE}/{domain}/*/*/*/{}/*/*/*/{}/{}/{}/*",
        EntityKind::Service.code(),
        mangle(name),
        mangle(ty.dds_name),
        mangle(ty.hash)
    )
}

/// An entity's GID: XXH3-128 of its liveliness key expression.
pub fn gid(liveliness_keyexpr: &str) -> [u8; GID_LEN] {
    xxhash_rust::xxh3::xxh3_128(liveliness_keyexpr.as_bytes()).to_le_bytes()
}

/// The attachment of a sample or a reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Attachment {
    /// The sender's sequence number (a reply repeats its request's).
    pub sequence: i64,
    /// When it was sent, ns since the Unix epoch.
    pub timestamp_ns: i64,
    /// The publisher's GID (a reply carries its client's).
    pub gid: [u8; GID_LEN],
}

impl Attachment {
    /// The attachment's bytes.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut bytes = Vec::with_capacity(ATTACHMENT_LEN);
        bytes.extend(self.sequence.to_le_bytes());
        bytes.extend(self.timestamp_ns.to_le_bytes());
        bytes.push(GID_LEN as u8);
        bytes.extend(self.gid);
        bytes
    }

    /// Reads an attachment; `None` unless it is one (length, GID length).
    pub fn from_bytes(bytes: &[u8]) -> Option<Attachment> {
        if bytes.len() != ATTACHMENT_LEN || bytes[16] as usize != GID_LEN {
            return None;
        }
        let i64_at = |at: usize| {
            let b: [u8; 8] = bytes[at..at + 8].try_into().ok()?;
            Some(i64::from_le_bytes(b))
        };
        Some(Attachment {
            sequence: i64_at(0)?,
            timestamp_ns: i64_at(8)?,
            gid: bytes[17..].try_into().ok()?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const GRID: RosType = RosType {
        dds_name: "nav_msgs::msg::dds_::OccupancyGrid_",
        hash: "RIHS01_8d348150c12913a31ee0ec170fbf25089e4745d17035792a1ba94d6f0bc0cfc7",
    };

    fn node() -> NodeInfo {
        NodeInfo {
            domain: 7,
            zid: "a1b2".into(),
            node_id: 0,
            namespace: "/isochron".into(),
            name: "costmap_bridge".into(),
            enclave: "/".into(),
        }
    }

    #[test]
    fn data_keys_drop_the_outer_slashes() {
        assert_eq!(
            data_keyexpr(7, "/isochron/activity_costmap", &GRID),
            format!(
                "7/isochron/activity_costmap/nav_msgs::msg::dds_::OccupancyGrid_/{}",
                GRID.hash
            )
        );
    }

    #[test]
    fn tokens_name_node_and_entity() {
        assert_eq!(
            liveliness_keyexpr(&node(), None),
            "@ros2_lv/7/a1b2/0/0/NN/%/%isochron/costmap_bridge"
        );
        let latched = Qos {
            reliable: true,
            transient_local: true,
            depth: 1,
        };
        let entity = (
            3,
            EntityKind::Publisher,
            "/isochron/activity_costmap",
            &GRID,
            latched,
        );
        assert_eq!(
            liveliness_keyexpr(&node(), Some(entity)),
            format!(
                "@ros2_lv/7/a1b2/0/3/MP/%/%isochron/costmap_bridge/%isochron%activity_costmap/nav_msgs::msg::dds_::OccupancyGrid_/{}/:1:,1:,:,:,,",
                GRID.hash
            )
        );
        assert_eq!(Qos::SERVICES.token_field(), "::,10:,:,:,,");
    }

    /// The pattern matches a server's token (any session, node, QoS) and no
    /// client's, nor another service's.
    #[test]
    fn the_servers_pattern_matches_every_server_of_the_service() {
        use zenoh::key_expr::KeyExpr;
        let route = RosType {
            dds_name: "nav2_msgs::srv::dds_::DynamicEdges_",
            hash: "RIHS01_857b",
        };
        let name = "/route_server/DynamicEdgesScorer/adjust_edges";
        let server = NodeInfo {
            namespace: "/".into(),
            name: "route_server".into(),
            ..node()
        };
        let token =
            |kind, name| liveliness_keyexpr(&server, Some((4, kind, name, &route, Qos::SERVICES)));
        let pattern = KeyExpr::try_from(servers_keyexpr(7, name, &route)).unwrap();
        let matches = |key: String| pattern.intersects(&KeyExpr::try_from(key).unwrap());
        assert!(matches(token(EntityKind::Service, name)));
        assert!(!matches(token(EntityKind::Client, name)));
        assert!(!matches(token(EntityKind::Service, "/other/adjust_edges")));
    }

    #[test]
    fn attachments_round_trip_and_refuse_other_lengths() {
        let a = Attachment {
            sequence: 5,
            timestamp_ns: 1_700_000_000_000_000_000,
            gid: gid("@ros2_lv/0/x/0/0/NN/%/%/n"),
        };
        let bytes = a.to_bytes();
        assert_eq!(bytes.len(), ATTACHMENT_LEN);
        assert_eq!(bytes[16], 16);
        assert_eq!(Attachment::from_bytes(&bytes), Some(a));
        assert_eq!(Attachment::from_bytes(&bytes[..32]), None);
        let mut wrong = bytes.clone();
        wrong[16] = 24;
        assert_eq!(Attachment::from_bytes(&wrong), None);
    }
}
