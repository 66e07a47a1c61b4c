//! The bridge's ROS 2 output: the node `/isochron/costmap_bridge` with a
//! [`Publisher`] per topic of [`crate::spec`] and the planning services, on DDS
//! and, when configured, on Zenoh in rmw_zenoh's format; and, with a route
//! graph, its links to the route server ([`crate::route_server`]).
//!
//! The DDS participant joins `costmap.ros_domain_id` (else `$ROS_DOMAIN_ID`, else 0)
//! and uses the network interfaces of `costmap.dds_interfaces` (else all; only
//! loopback when `ROS_LOCALHOST_ONLY=1` or `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`):
//! RustDDS announces only their addresses and multicasts only on them, but binds
//! its sockets to 0.0.0.0 regardless (hard-coded in 0.15) — a hard limit is the
//! unit's `IPAddressAllow=`/`IPAddressDeny=` or a firewall (docs/security.md).
//!
//! With `costmap.security_dir` the participant runs DDS Security (SROS2) with the
//! bridge's enclave, as the link does: only robots of the site's keystore whose
//! permissions allow it read the topics and call the services, and no other
//! participant can write on the bridge's topics or answer its services.

use std::net::IpAddr;
use std::path::PathBuf;

use isochron_dds::RosNode;
use isochron_planning::query::{PlanKind, PlanRequest, PlanResponse};
use isochron_runtime::stage::Context;
use isochron_zenoh::RosZenoh;

use crate::dds::{DdsCaller, DdsService};
use crate::error::RosError;
use crate::msgs::{CostmapFilterInfo, MarkerArray, OccupancyGrid, OccupancyGridUpdate, PoseArray};
use crate::plan::{PlanCounts, PlanServices, Serve};
use crate::publisher::Publisher;
use crate::route_server::{Caller, RouteLink, RouteServerLink};
use crate::spec::{
    FORECAST, GRID, MARKERS, Names, PEOPLE, PEOPLE_MARKERS, ROUTE_SERVER, SERVICES,
    SPEED_FILTER_INFO, SPEED_MASK, UPDATES,
};
use crate::zenoh::{ZenohCaller, ZenohService};

/// The bridge's ROS 2 node: `/isochron/<NODE>`.
pub const NODE: &str = "costmap_bridge";

/// Where and how the bridge talks ROS 2.
#[derive(Debug, Clone, PartialEq)]
pub struct RosSettings {
    /// DDS domain (ROS_DOMAIN_ID).
    pub domain_id: u16,
    /// Network interfaces (their addresses) DDS may use; empty: all.
    pub interfaces: Vec<IpAddr>,
    /// The names of the topics and services, on every transport.
    pub names: Names,
    /// The bridge's SROS2 enclave (`costmap.security_dir`): DDS Security with
    /// it, none without.
    pub enclave: Option<PathBuf>,
    /// The same topics and services on Zenoh in rmw_zenoh's format, if configured.
    pub zenoh: Option<isochron_zenoh::Settings>,
    /// Call the route server's `DynamicEdgesScorer` (a route graph is
    /// configured).
    pub route_server: bool,
}

/// The ROS 2 node of the bridge: its publishers and planning services.
pub struct RosOutput {
    /// The cost map ([`GRID`]).
    pub grid: Publisher<OccupancyGrid>,
    /// The cost map's changed rectangles ([`UPDATES`]).
    pub updates: Publisher<OccupancyGridUpdate>,
    /// The confirmed people ([`PEOPLE`]).
    pub people: Publisher<PoseArray>,
    /// The site's markers, latched ([`MARKERS`]).
    pub markers: Publisher<MarkerArray>,
    /// The confirmed people drawn ([`PEOPLE_MARKERS`]).
    pub people_markers: Publisher<MarkerArray>,
    /// The speed filter's info, latched ([`SPEED_FILTER_INFO`]).
    pub speed_filter_info: Publisher<CostmapFilterInfo>,
    /// The speed filter's mask, latched ([`SPEED_MASK`]).
    pub speed_mask: Publisher<OccupancyGrid>,
    /// The forecast cost map, latched ([`FORECAST`]).
    pub forecast: Publisher<OccupancyGrid>,
    /// The planning services of each transport: DDS's, then Zenoh's.
    plans: Vec<Box<dyn Serve>>,
    /// The links to the route server, one per transport (none without
    /// [`RosSettings::route_server`]).
    pub route_links: Vec<RouteLink>,
    /// The Zenoh session, open while the output is.
    _zenoh: Option<RosZenoh>,
    ros: RosNode,
}

impl RosOutput {
    /// Joins the DDS domain and creates the node `/isochron/costmap_bridge` with
    /// its publishers and services, and the same on Zenoh if configured.
    pub fn start(settings: &RosSettings) -> Result<RosOutput, RosError> {
        let names = &settings.names;
        let mut ros = RosNode::start(
            settings.domain_id,
            &settings.interfaces,
            NODE,
            settings.enclave.as_deref(),
        )?;
        let zenoh = match &settings.zenoh {
            Some(z) => Some(RosZenoh::open(z, "/isochron", NODE)?),
            None => None,
        };
        // On Zenoh the services are declared first: their entity ids 1 to 3, the
        // publishers' 4 to 11.
        let zenoh_plans = match &zenoh {
            Some(z) => Some(PlanServices::new(
                SERVICES
                    .iter()
                    .map(|s| ZenohService::start(z, s, names.of(&s.config)))
                    .collect::<Result<_, _>>()?,
            )),
            None => None,
        };
        let (r, z) = (&mut ros, zenoh.as_ref());
        let grid = Publisher::start(&GRID, names.of(&GRID.config), r, z)?;
        let updates = Publisher::start(&UPDATES, names.of(&UPDATES.config), r, z)?;
        let people = Publisher::start(&PEOPLE, names.of(&PEOPLE.config), r, z)?;
        let markers = Publisher::start(&MARKERS, names.of(&MARKERS.config), r, z)?;
        let people_markers =
            Publisher::start(&PEOPLE_MARKERS, names.of(&PEOPLE_MARKERS.config), r, z)?;
        let speed_filter_info = Publisher::start(
            &SPEED_FILTER_INFO,
            names.of(&SPEED_FILTER_INFO.config),
            r,
            z,
        )?;
        let speed_mask = Publisher::start(&SPEED_MASK, names.of(&SPEED_MASK.config), r, z)?;
        let forecast = Publisher::start(&FORECAST, names.of(&FORECAST.config), r, z)?;
        let dds_plans = PlanServices::<DdsService>::new(
            SERVICES
                .iter()
                .map(|s| DdsService::start(&ros, s, names.of(&s.config)))
                .collect::<Result<_, _>>()?,
        );
        let mut route_links = Vec::new();
        if settings.route_server {
            let name = names.of(&ROUTE_SERVER.config);
            let dds: Box<dyn Caller> = Box::new(DdsCaller::start(&ros, name, &ROUTE_SERVER.ty)?);
            route_links.push(RouteServerLink::new(dds, name));
            if let Some(z) = &zenoh {
                let caller = ZenohCaller::start(z, name, &ROUTE_SERVER.ty)?;
                let caller: Box<dyn Caller> = Box::new(caller);
                route_links.push(RouteServerLink::new(caller, format!("{name} (Zenoh)")));
            }
        }
        let mut plans: Vec<Box<dyn Serve>> = vec![Box::new(dds_plans)];
        if let (Some(zenoh_plans), Some(z)) = (zenoh_plans, &settings.zenoh) {
            plans.push(Box::new(zenoh_plans));
            log_zenoh(z);
        }
        Ok(RosOutput {
            grid,
            updates,
            people,
            markers,
            people_markers,
            speed_filter_info,
            speed_mask,
            forecast,
            plans,
            route_links,
            _zenoh: zenoh,
            ros,
        })
    }

    /// Answers the requests of the planning services that are due, on every
    /// transport, with `answer` — the same function that answers `<prefix>/plan`
    /// over iceoryx2; returns how many were answered ([`Serve::serve`]: malformed
    /// requests get `STATUS_BAD_REQUEST`, floods are dropped, both counted in
    /// `cx`).
    pub fn serve_plans(
        &mut self,
        cx: &mut Context,
        mut answer: impl FnMut(PlanKind, &PlanRequest) -> PlanResponse,
    ) -> usize {
        self.plans
            .iter_mut()
            .map(|transport| transport.serve(cx, &mut answer))
            .sum()
    }

    /// What the planning services did so far, on every transport.
    pub fn plan_counts(&self) -> PlanCounts {
        self.plans
            .iter()
            .fold(PlanCounts::default(), |sum, transport| {
                sum + transport.counts()
            })
    }

    /// Subscribers matched with the grid publisher on DDS: the remote readers
    /// discovery knows on the grid topic whose requested QoS the writer offers.
    pub fn grid_subscribers(&self) -> usize {
        self.grid.dds_readers(&self.ros)
    }
}

/// Says that the output is on Zenoh too, and how.
fn log_zenoh(z: &isochron_zenoh::Settings) {
    tracing::info!(
        "ROS 2 on Zenoh (rmw_zenoh's format) too: domain {}, {} to {}, listening on {}",
        z.domain,
        if z.mode == isochron_zenoh::Mode::Client {
            "client"
        } else {
            "peer"
        },
        z.connect.join(", "),
        if z.listen.is_empty() {
            "nothing".to_string()
        } else {
            z.listen.join(", ")
        }
    );
}

/// The interfaces DDS may use: `configured`, else loopback only when ROS's own
/// variables ask for it (`ROS_LOCALHOST_ONLY=1`,
/// `ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`), else all (empty).
pub fn interfaces(configured: &[IpAddr]) -> Vec<IpAddr> {
    if !configured.is_empty() {
        return configured.to_vec();
    }
    let localhost_only = std::env::var("ROS_LOCALHOST_ONLY").is_ok_and(|v| v.trim() == "1")
        || std::env::var("ROS_AUTOMATIC_DISCOVERY_RANGE")
            .is_ok_and(|v| v.trim().eq_ignore_ascii_case("LOCALHOST"));
    if localhost_only {
        vec![IpAddr::from([127, 0, 0, 1])]
    } else {
        Vec::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::topic_name;

    #[test]
    fn interfaces_prefer_the_config() {
        let lo: IpAddr = "127.0.0.1".parse().unwrap();
        assert_eq!(interfaces(&[lo]), vec![lo]);
        assert!(topic_name("/isochron/activity_costmap").is_ok());
        assert!(topic_name("/bad//name").is_err());
        assert!(topic_name("/bad name").is_err());
    }
}
