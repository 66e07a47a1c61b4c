//! isochron-census: people counted from a detector's boxes — tracks on the
//! floor ([`tracker`]), and from them people per zone now, each minute's
//! Δt-weighted mean and peak, each visit's dwell and each line crossing
//! ([`counts`]). Pure computation on one plane (floor metres, or image pixels
//! for a camera without floor points): no I/O, no clock, so the gate, the
//! replay and the benchmarks count alike.

pub mod counts;
pub mod tracker;
