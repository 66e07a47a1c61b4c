//! A planning request's fields as the planner's request, and the planner's
//! answer as a response's fields: CDR decoding and checks.

use byteorder::{BigEndian, LittleEndian};
use rustdds::serialization::from_bytes;
use serde::de::DeserializeOwned;

use isochron_planning::plan_service::{offline_plan_of, ranking_of};
use isochron_planning::query::{
    PLAN_FLAG_INFINITE, PLAN_MAX_ROUTES, PLAN_NAME_LEN, PlanGraphPath, PlanKind, PlanRequest,
    PlanResponse, PlanStatus,
};

use crate::msgs::{
    CostPoint, GraphPath, PlanGraphRequest, PlanGraphResponse, PlanNowRequest, PlanNowResponse,
    PlanOfflineRequest, PlanOfflineResponse, RouteCost, Window as WindowMsg,
};

/// Largest request body decoded: a `PlanNow` of 16 names of 32 bytes is < 700.
pub const MAX_REQUEST_BYTES: usize = 4096;

/// Decodes `body` (CDR, big- or little-endian) as a `T`.
fn cdr<T: DeserializeOwned>(body: &[u8], big_endian: bool) -> Result<T, String> {
    let decoded = if big_endian {
        from_bytes::<T, BigEndian>(body)
    } else {
        from_bytes::<T, LittleEndian>(body)
    };
    decoded.map(|(t, _)| t).map_err(|e| e.to_string())
}

/// The iceoryx2 request of a request body of `kind`, validated like one.
pub fn plan_request(kind: PlanKind, body: &[u8], big_endian: bool) -> Result<PlanRequest, String> {
    if body.len() > MAX_REQUEST_BYTES {
        return Err(format!(
            "a request of {} bytes; at most {MAX_REQUEST_BYTES} are read",
            body.len()
        ));
    }
    let request = match kind {
        PlanKind::Now => {
            let wire: PlanNowRequest = cdr(body, big_endian)?;
            if wire.routes.is_empty() || wire.routes.len() > PLAN_MAX_ROUTES {
                return Err(format!(
                    "expected 1 to {PLAN_MAX_ROUTES} routes, found {}",
                    wire.routes.len()
                ));
            }
            for name in &wire.routes {
                check_route_name(&name.0)?;
            }
            let names: Vec<&str> = wire.routes.iter().map(|r| r.0.as_str()).collect();
            PlanRequest::new(PlanKind::Now, &names)
        }
        PlanKind::Graph => {
            let wire: PlanGraphRequest = cdr(body, big_endian)?;
            let mut request = PlanRequest::graph(wire.from_node, wire.to_node);
            request.start_minute = wire.start_minute as u32;
            request.end_minute = wire.end_minute as u32;
            request.step_min = wire.step_min as u32;
            request.weekday = wire.weekday as u32;
            request
        }
        _ => {
            let wire: PlanOfflineRequest = cdr(body, big_endian)?;
            check_route_name(&wire.route.0)?;
            let mut request = PlanRequest::new(PlanKind::Offline, &[&wire.route.0]);
            request.start_minute = wire.start_minute as u32;
            request.end_minute = wire.end_minute as u32;
            request.step_min = wire.step_min as u32;
            request.weekday = wire.weekday as u32;
            request
        }
    };
    request.validate().map_err(|e| e.to_string())?;
    Ok(request)
}

/// Route names a ROS 2 request may carry: at most [`PLAN_NAME_LEN`] bytes each.
fn check_route_name(name: &str) -> Result<(), String> {
    if name.is_empty() || name.len() > PLAN_NAME_LEN {
        return Err(format!(
            "route name '{name}': expected 1 to {PLAN_NAME_LEN} bytes"
        ));
    }
    Ok(())
}

/// A `PlanOffline` response from the planner's answer.
pub fn offline_response(r: &PlanResponse) -> PlanOfflineResponse {
    if r.status != PlanStatus::Ok as u32 {
        return PlanOfflineResponse {
            status: r.status as u8,
            message: r.message(),
            windows: Vec::new(),
            curve: Vec::new(),
            infinite: false,
        };
    }
    let plan = offline_plan_of(r);
    PlanOfflineResponse {
        status: r.status as u8,
        message: r.message(),
        windows: plan
            .windows
            .iter()
            .map(|w| WindowMsg {
                start_minute: w.start as u16,
                end_minute: w.end as u16,
                cost: w.cost,
            })
            .collect(),
        curve: plan
            .curve
            .iter()
            .map(|p| CostPoint {
                minute: p.minute as u16,
                cost: p.cost,
            })
            .collect(),
        infinite: r.route_count > 0 && r.routes[0].flags & PLAN_FLAG_INFINITE != 0,
    }
}

/// A `PlanNow` response from the planner's answer.
pub fn now_response(r: &PlanResponse) -> PlanNowResponse {
    let ok = r.status == PlanStatus::Ok as u32;
    PlanNowResponse {
        status: r.status as u8,
        message: r.message(),
        t_star: if ok { r.t_star as u16 } else { 0 },
        routes: if ok {
            ranking_of(r)
                .into_iter()
                .map(|x| RouteCost {
                    route: x.name,
                    cost2: x.cost2,
                    cost1: x.cost1,
                    short_term: x.short_term,
                    infinite: x.infinite,
                    estimated: x.estimated,
                    no_long_term: x.no_long_term,
                })
                .collect()
        } else {
            Vec::new()
        },
    }
}

/// A `PlanGraph` response from the planner's answer.
pub fn graph_response(r: &PlanResponse) -> PlanGraphResponse {
    let empty = || graph_path(&PlanGraphPath::EMPTY);
    let mut response = PlanGraphResponse {
        status: r.status as u8,
        message: r.message(),
        windows: Vec::new(),
        window_paths: Vec::new(),
        curve: Vec::new(),
        best: empty(),
        baseline: empty(),
    };
    if r.status != PlanStatus::Ok as u32 {
        return response;
    }
    let plan = offline_plan_of(r);
    let windows = (r.window_count as usize).min(r.windows.len());
    response.windows = plan
        .windows
        .iter()
        .map(|w| WindowMsg {
            start_minute: w.start as u16,
            end_minute: w.end as u16,
            cost: w.cost,
        })
        .collect();
    response.window_paths = r.graph_windows[..windows].iter().map(graph_path).collect();
    response.curve = plan
        .curve
        .iter()
        .map(|p| CostPoint {
            minute: p.minute as u16,
            cost: p.cost,
        })
        .collect();
    response.best = graph_path(&r.graph_best);
    response.baseline = graph_path(&r.graph_baseline);
    response
}

/// A `GraphPath` from its wire form.
fn graph_path(p: &PlanGraphPath) -> GraphPath {
    GraphPath {
        departure_minute: p.departure_minute as u16,
        nodes: p.node_ids().to_vec(),
        edges: p.edge_ids().to_vec(),
        cost: p.cost as f64,
        activity_cost: p.activity_cost as f64,
        length_m: p.length_m as f64,
        duration_s: p.duration_s as f64,
        unknown_edges: p.unknown_edges.min(u16::MAX as u32) as u16,
    }
}
