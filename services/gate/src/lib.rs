//! isochron-gate: turns short-term activity into events, and runs the costly
//! detector only on frames an event gates (the paper's hybrid scheme).
//!
//! * [`events`]: per zone and kind, an event starts when S1 or S2 summed over the
//!   zone exceeds its threshold — a floor while the long-term model is cold, the
//!   long-term mean plus k·sigma at t* once it is warm — and ends after staying
//!   below it for a hold time;
//! * [`gate`]: the per-camera gate: zones, event trackers, and which frames to
//!   detect (N per event, or one every M seconds while an event lasts);
//! * `people`: the people the detector confirmed, and where they and activity lie
//!   on the block grid (the crop a detection searches);
//! * [`ring`]: the recent frames the detector reads;
//! * [`detector`]: OpenCV's HOG people detector, or an ONNX model via OpenCV dnn;
//! * [`worker`]: the detector thread, so a slow detector never stalls activity;
//! * [`stage`]: the service's stage for the runtime (`frames` + `activity` in,
//!   `events` + `detections` out).

pub mod detector;
pub mod events;
pub mod gate;
mod people;
pub mod ring;
pub mod stage;
pub mod worker;
