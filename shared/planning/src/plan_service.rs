//! The planning service over iceoryx2: request-response on `<prefix>/plan`
//! ([`PlanRequest`] → [`PlanResponse`], the fixed-size `#[repr(C)]` types of
//! [`crate::query`]), served by the cost map bridge ([`PlanServer`]), asked by
//! `isochron plan now`, `isochron costmap snapshot` and robot-side processes on the
//! same box ([`PlanClient`]). Both ends of the protocol live here.
//!
//! An event service of the same name wakes the bridge when a client notifies it
//! after sending a request ([`PlanClient`] does); clients that do not are answered
//! within the bridge's loop period. [`answer_offline`], [`answer_now`] and
//! [`answer_graph`] turn plans into responses, [`offline_plan_of`] and
//! [`ranking_of`] turn them back (a graph answer's paths are read as they are).

use std::time::{Duration, Instant};

use iceoryx2::port::client::Client;
use iceoryx2::port::listener::Listener;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::server::Server;
use iceoryx2::prelude::*;
use iceoryx2::service::port_factory::PortFactory as _;
use iceoryx2::service::port_factory::request_response::PortFactory;
use isochron_runtime::ipc::{Ipc, Ipc2, IpcError};
use isochron_wire::{WireError, fixed_str, to_fixed};

use crate::graph_plan::{GraphPath, GraphPlan};
use crate::plan::{CurvePoint, DayRange, OfflinePlan, RouteNow, Window};
use crate::query::{
    PLAN_CURVE_LEN, PLAN_FLAG_ESTIMATED, PLAN_FLAG_INFINITE, PLAN_FLAG_NO_LONG_TERM,
    PLAN_GRAPH_MAX_EDGES, PLAN_MAX_ROUTES, PLAN_MAX_WINDOWS, PLAN_NAME_LEN, PlanGraphPath,
    PlanKind, PlanRequest, PlanResponse, PlanRouteCost, PlanStatus, PlanWindow,
};

/// Most clients connected at once.
const MAX_CLIENTS: usize = 16;

/// Why [`PlanClient::request`] got no usable answer.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RequestError {
    /// No server on `<prefix>/plan` within the timeout.
    #[error("no isochron-costmap is serving plans on this site: is it running (isochron status)?")]
    NoServer,
    /// The request could not be sent.
    #[error("sending the plan request: {0}")]
    Send(String),
    /// The response could not be received.
    #[error("receiving the plan response: {0}")]
    Receive(String),
    /// The response arrived but does not validate.
    #[error("the plan response is malformed: {0}")]
    Malformed(WireError),
    /// The server went away without answering.
    #[error("isochron-costmap dropped the request without an answer")]
    Dropped,
    /// No answer within the timeout.
    #[error("no answer from isochron-costmap within {0:?}")]
    Timeout(Duration),
}

type Factory = PortFactory<Ipc2, PlanRequest, (), PlanResponse, ()>;

fn err(context: &str, e: impl std::fmt::Display) -> IpcError {
    IpcError {
        context: context.to_string(),
        detail: format!("{e}"),
        permanent: false,
    }
}

fn open(
    ipc: &Ipc,
) -> Result<
    (
        Factory,
        iceoryx2::service::port_factory::event::PortFactory<Ipc2>,
    ),
    IpcError,
> {
    let name = ipc.names().plan();
    let service_name: ServiceName = name
        .as_str()
        .try_into()
        .map_err(|e| err(&format!("invalid service name '{name}'"), e))?;
    let rr = ipc
        .node()
        .service_builder(&service_name)
        .request_response::<PlanRequest, PlanResponse>()
        .max_clients(MAX_CLIENTS)
        .max_servers(1)
        .max_active_requests_per_client(2)
        .max_response_buffer_size(2)
        .open_or_create()
        .map_err(|e| err(&format!("opening the planning service '{name}'"), e))?;
    let event = ipc
        .node()
        .service_builder(&service_name)
        .event()
        .open_or_create()
        .map_err(|e| err(&format!("opening the planning event service '{name}'"), e))?;
    Ok((rr, event))
}

/// The bridge's end: receives requests, answers them. Attach it to a WaitSet to
/// wake on notified requests.
pub struct PlanServer {
    server: Server<Ipc2, PlanRequest, (), PlanResponse, ()>,
    listener: Listener<Ipc2>,
    _service: Factory,
}

impl std::fmt::Debug for PlanServer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("PlanServer")
    }
}

impl FileDescriptorBased for PlanServer {
    fn file_descriptor(&self) -> &FileDescriptor {
        self.listener.file_descriptor()
    }
}

impl SynchronousMultiplexing for PlanServer {}

impl PlanServer {
    /// Opens `<prefix>/plan` as its (only) server.
    pub fn new(ipc: &Ipc) -> Result<PlanServer, IpcError> {
        let (service, event) = open(ipc)?;
        let server = service.server_builder().create().map_err(|e| {
            err(
                "creating the planning server (is another isochron-costmap running?)",
                e,
            )
        })?;
        let listener = event
            .listener_builder()
            .create()
            .map_err(|e| err("creating the planning listener", e))?;
        Ok(PlanServer {
            server,
            listener,
            _service: service,
        })
    }

    /// Answers every pending request with `answer`; returns how many. Malformed
    /// requests get a [`PlanStatus::BadRequest`] answer and are counted in
    /// `rejected`.
    pub fn serve(
        &self,
        mut answer: impl FnMut(PlanKind, &PlanRequest) -> PlanResponse,
        rejected: &mut u64,
    ) -> Result<usize, IpcError> {
        let _ = self.listener.try_wait(|_| {});
        let mut n = 0;
        while let Some(active) = self
            .server
            .receive()
            .map_err(|e| err("receiving a plan request", e))?
        {
            let request = *active.payload();
            let response = match request.validate() {
                Ok(kind) => answer(kind, &request),
                Err(e) => {
                    *rejected += 1;
                    tracing::warn!("rejected a plan request: {e}");
                    PlanResponse::new(request.kind, PlanStatus::BadRequest, &e.to_string())
                }
            };
            if let Err(e) = active.send_copy(response) {
                tracing::warn!("a plan response could not be sent (client gone?): {e}");
            }
            n += 1;
        }
        Ok(n)
    }
}

/// A client of `<prefix>/plan`.
pub struct PlanClient {
    client: Client<Ipc2, PlanRequest, (), PlanResponse, ()>,
    notifier: Notifier<Ipc2>,
    service: Factory,
}

impl PlanClient {
    /// Connects to `<prefix>/plan`.
    pub fn new(ipc: &Ipc) -> Result<PlanClient, IpcError> {
        let (service, event) = open(ipc)?;
        let client = service
            .client_builder()
            .create()
            .map_err(|e| err("creating the planning client", e))?;
        let notifier = event
            .notifier_builder()
            .create()
            .map_err(|e| err("creating the planning notifier", e))?;
        Ok(PlanClient {
            client,
            notifier,
            service,
        })
    }

    /// Sends `request` and waits up to `timeout` for the answer.
    pub fn request(
        &self,
        request: PlanRequest,
        timeout: Duration,
    ) -> Result<PlanResponse, RequestError> {
        let deadline = Instant::now() + timeout;
        // The server may still be starting: wait for it within the timeout.
        while self.service.dynamic_config().number_of_servers() == 0 {
            if Instant::now() >= deadline {
                return Err(RequestError::NoServer);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        let pending = self
            .client
            .send_copy(request)
            .map_err(|e| RequestError::Send(format!("{e}")))?;
        let _ = self.notifier.notify();
        loop {
            if let Some(response) = pending
                .receive()
                .map_err(|e| RequestError::Receive(format!("{e}")))?
            {
                let response = *response.payload();
                response.validate().map_err(RequestError::Malformed)?;
                return Ok(response);
            }
            if !pending.is_connected() {
                return Err(RequestError::Dropped);
            }
            if Instant::now() >= deadline {
                return Err(RequestError::Timeout(timeout));
            }
            std::thread::sleep(Duration::from_millis(5));
        }
    }
}

fn finite_f32(v: f64) -> f32 {
    v as f32
}

/// The response to an off-line request for `plan`.
pub fn answer_offline(plan: &OfflinePlan) -> PlanResponse {
    let mut r = PlanResponse::new(PlanKind::Offline as u32, PlanStatus::Ok, "");
    r.route_count = 1;
    let best = plan.best.first();
    r.routes[0] = PlanRouteCost {
        name: to_fixed::<PLAN_NAME_LEN>(&plan.route),
        cost2: best.map_or(f32::INFINITY, |p| finite_f32(p.cost)),
        cost1: best.map_or(f32::INFINITY, |p| finite_f32(p.cost)),
        short_term: 0.0,
        flags: if plan.never_active.is_empty() {
            0
        } else {
            PLAN_FLAG_INFINITE
        },
    };
    r.t_star = best.map_or(0, |p| p.minute);
    r.curve_start_minute = plan.range.start;
    r.curve_step_min = plan.range.step;
    r.curve_len = plan.curve.len().min(PLAN_CURVE_LEN) as u32;
    for (slot, p) in r.curve.iter_mut().zip(&plan.curve) {
        *slot = finite_f32(p.cost);
    }
    r.window_count = plan.windows.len().min(PLAN_MAX_WINDOWS) as u32;
    for (slot, w) in r.windows.iter_mut().zip(&plan.windows) {
        *slot = PlanWindow {
            start_minute: w.start,
            end_minute: w.end,
            cost: finite_f32(w.cost),
            reserved: 0,
        };
    }
    if !plan.never_active.is_empty() {
        r.message = to_fixed(&format!("never active: {}", plan.never_active.join(", ")));
    }
    r
}

/// The response to a graph request for `plan`: the curve, the windows with the
/// cheapest path of each, the best departure and the baseline; `t_star` is the
/// best departure's minute of the cycle. A path with more than
/// [`PLAN_GRAPH_MAX_EDGES`] edges does not fit: [`PlanStatus::Failed`] says so.
pub fn answer_graph(plan: &GraphPlan) -> PlanResponse {
    let kind = PlanKind::Graph as u32;
    let paths = plan.windows.iter().map(|w| &w.path);
    if let Some(long) = paths
        .chain(&plan.best)
        .chain([&plan.baseline])
        .find(|p| p.edges.len() > PLAN_GRAPH_MAX_EDGES)
    {
        let message = format!(
            "a path of {} edges; at most {PLAN_GRAPH_MAX_EDGES} fit in an answer",
            long.edges.len()
        );
        return PlanResponse::new(kind, PlanStatus::Failed, &message);
    }
    let mut r = PlanResponse::new(kind, PlanStatus::Ok, "");
    r.t_star = plan.best.first().map_or(0, |p| p.t_star);
    r.curve_start_minute = plan.range.start;
    r.curve_step_min = plan.range.step;
    r.curve_len = plan.curve.len().min(PLAN_CURVE_LEN) as u32;
    for (slot, p) in r.curve.iter_mut().zip(&plan.curve) {
        *slot = finite_f32(p.cost);
    }
    r.window_count = plan.windows.len().min(PLAN_MAX_WINDOWS) as u32;
    for ((slot, path), w) in r
        .windows
        .iter_mut()
        .zip(r.graph_windows.iter_mut())
        .zip(&plan.windows)
    {
        *slot = PlanWindow {
            start_minute: w.window.start,
            end_minute: w.window.end,
            cost: finite_f32(w.window.cost),
            reserved: 0,
        };
        *path = graph_path(&w.path);
    }
    if let Some(best) = plan.best.first() {
        r.graph_best = graph_path(best);
    }
    r.graph_baseline = graph_path(&plan.baseline);
    r
}

/// `path` on the wire (at most [`PLAN_GRAPH_MAX_EDGES`] edges; checked above).
fn graph_path(path: &GraphPath) -> PlanGraphPath {
    let mut wire = PlanGraphPath {
        departure_minute: path.minute,
        node_count: path.nodes.len().min(PLAN_GRAPH_MAX_EDGES + 1) as u32,
        edge_count: path.edges.len().min(PLAN_GRAPH_MAX_EDGES) as u32,
        unknown_edges: path.unknown_edges as u32,
        cost: finite_f32(path.cost),
        activity_cost: finite_f32(path.activity_cost),
        length_m: finite_f32(path.length_m),
        duration_s: finite_f32(path.duration_s),
        ..PlanGraphPath::EMPTY
    };
    for (slot, &id) in wire.nodes.iter_mut().zip(&path.nodes) {
        *slot = id;
    }
    for (slot, &id) in wire.edges.iter_mut().zip(&path.edges) {
        *slot = id;
    }
    wire
}

/// The response to a real-time request: the ranking at `t_star`.
pub fn answer_now(ranked: &[RouteNow], t_star: u32) -> PlanResponse {
    let mut r = PlanResponse::new(PlanKind::Now as u32, PlanStatus::Ok, "");
    r.t_star = t_star;
    r.route_count = ranked.len().min(PLAN_MAX_ROUTES) as u32;
    for (slot, route) in r.routes.iter_mut().zip(ranked) {
        let mut flags = 0;
        if route.infinite {
            flags |= PLAN_FLAG_INFINITE;
        }
        if route.estimated {
            flags |= PLAN_FLAG_ESTIMATED;
        }
        if route.no_long_term {
            flags |= PLAN_FLAG_NO_LONG_TERM;
        }
        *slot = PlanRouteCost {
            name: to_fixed::<PLAN_NAME_LEN>(&route.name),
            cost2: finite_f32(route.cost2),
            cost1: finite_f32(route.cost1),
            short_term: finite_f32(route.short_term),
            flags,
        };
    }
    r
}

/// The ranking in a real-time response.
pub fn ranking_of(r: &PlanResponse) -> Vec<RouteNow> {
    r.routes[..(r.route_count as usize).min(PLAN_MAX_ROUTES)]
        .iter()
        .map(|c| RouteNow {
            name: fixed_str(&c.name),
            cost1: c.cost1 as f64,
            short_term: c.short_term as f64,
            cost2: c.cost2 as f64,
            infinite: c.flags & PLAN_FLAG_INFINITE != 0,
            estimated: c.flags & PLAN_FLAG_ESTIMATED != 0,
            no_long_term: c.flags & PLAN_FLAG_NO_LONG_TERM != 0,
        })
        .collect()
}

/// The plan in an off-line response (the segments that never saw activity are
/// known only by the flag and the message).
pub fn offline_plan_of(r: &PlanResponse) -> OfflinePlan {
    let step = r.curve_step_min.max(1);
    let curve: Vec<CurvePoint> = r.curve[..(r.curve_len as usize).min(PLAN_CURVE_LEN)]
        .iter()
        .enumerate()
        .map(|(k, &c)| CurvePoint {
            minute: (r.curve_start_minute + k as u32 * step) % 1440,
            cost: c as f64,
        })
        .collect();
    let windows: Vec<Window> = r.windows[..(r.window_count as usize).min(PLAN_MAX_WINDOWS)]
        .iter()
        .map(|w| Window {
            start: w.start_minute,
            end: w.end_minute,
            cost: w.cost as f64,
        })
        .collect();
    let mut best: Vec<CurvePoint> = curve
        .iter()
        .filter(|p| p.cost.is_finite())
        .copied()
        .collect();
    best.sort_by(|a, b| a.cost.total_cmp(&b.cost));
    best.truncate(5);
    let message = r.message();
    OfflinePlan {
        route: fixed_str(&r.routes[0].name),
        range: DayRange {
            start: r.curve_start_minute,
            end: (r.curve_start_minute + curve.len() as u32 * step) % 1440,
            step,
            cycle_offset: 0,
        },
        curve,
        never_active: message
            .strip_prefix("never active: ")
            .map(|s| s.split(", ").map(str::to_string).collect())
            .unwrap_or_default(),
        windows,
        best,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn answers_carry_the_plan() {
        let plan = OfflinePlan {
            route: "r".into(),
            range: DayRange {
                start: 600,
                end: 720,
                step: 30,
                cycle_offset: 0,
            },
            curve: vec![
                CurvePoint {
                    minute: 600,
                    cost: 5.0,
                },
                CurvePoint {
                    minute: 630,
                    cost: 1.0,
                },
                CurvePoint {
                    minute: 660,
                    cost: f64::NAN,
                },
                CurvePoint {
                    minute: 690,
                    cost: 7.0,
                },
            ],
            never_active: vec![],
            windows: vec![Window {
                start: 630,
                end: 660,
                cost: 1.0,
            }],
            best: vec![CurvePoint {
                minute: 630,
                cost: 1.0,
            }],
        };
        let r = answer_offline(&plan);
        assert_eq!(r.validate(), Ok(PlanStatus::Ok));
        let back = offline_plan_of(&r);
        assert_eq!(back.route, "r");
        assert_eq!(back.windows, plan.windows);
        assert_eq!(back.curve.len(), 4);
        assert_eq!(back.curve[1], plan.curve[1]);
        assert!(back.curve[2].cost.is_nan());
        assert_eq!(back.best[0].minute, 630);

        let ranked = vec![
            RouteNow {
                name: "a".into(),
                cost1: 1.0,
                short_term: 2.0,
                cost2: 3.0,
                infinite: false,
                estimated: true,
                no_long_term: false,
            },
            RouteNow {
                name: "b".into(),
                cost1: f64::INFINITY,
                short_term: 0.0,
                cost2: f64::INFINITY,
                infinite: true,
                estimated: false,
                no_long_term: false,
            },
        ];
        let r = answer_now(&ranked, 870);
        assert_eq!(r.t_star, 870);
        assert_eq!(ranking_of(&r), ranked);
    }

    #[test]
    fn graph_answers_carry_the_paths_and_refuse_what_does_not_fit() {
        use crate::graph_plan::GraphWindow;
        let path = |minute: u32, edges: Vec<u16>, cost: f64| GraphPath {
            t_star: minute,
            minute,
            nodes: std::iter::once(1)
                .chain(edges.iter().map(|e| e + 100))
                .collect(),
            edges,
            cost,
            activity_cost: cost - 3.0,
            length_m: 3.0,
            duration_s: 6.0,
            unknown_edges: 0,
        };
        let plan = GraphPlan {
            range: DayRange {
                start: 480,
                end: 540,
                step: 30,
                cycle_offset: 0,
            },
            curve: vec![
                CurvePoint {
                    minute: 480,
                    cost: 3.0,
                },
                CurvePoint {
                    minute: 510,
                    cost: 8.0,
                },
            ],
            windows: vec![GraphWindow {
                window: Window {
                    start: 480,
                    end: 510,
                    cost: 3.0,
                },
                path: path(480, vec![11, 12], 3.0),
            }],
            best: vec![path(480, vec![11, 12], 3.0)],
            baseline: path(525, vec![11, 12], 199.0),
        };
        let r = answer_graph(&plan);
        assert_eq!(r.validate(), Ok(PlanStatus::Ok));
        assert_eq!((r.t_star, r.curve_len, r.window_count), (480, 2, 1));
        assert_eq!(r.graph_best.node_ids(), [1, 111, 112]);
        assert_eq!(r.graph_best.edge_ids(), [11, 12]);
        assert_eq!(r.graph_windows[0].edge_ids(), [11, 12]);
        assert_eq!(r.graph_baseline.cost, 199.0);
        assert_eq!(r.graph_baseline.departure_minute, 525);
        let mut long = plan.clone();
        long.baseline = path(0, vec![7; PLAN_GRAPH_MAX_EDGES + 1], 1.0);
        let r = answer_graph(&long);
        assert_eq!(r.validate(), Ok(PlanStatus::Failed));
        assert!(r.message().contains("at most 255"), "{}", r.message());
    }
}
