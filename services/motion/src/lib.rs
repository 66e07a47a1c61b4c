//! isochron-motion: per-block motion features (density, flow vector, direction) from
//! consecutive GRAY8 frames — the first stage after capture (see docs/ARCHITECTURE.md,
//! 'Paper to code'; the paper's "Motion Detection").
//!
//! * [`kernel`]: the fused motion-flow kernel (temporal difference,
//!   motion-pixel test, spatial gradient, normal-flow sums per block): scalar
//!   reference, portable (LLVM-vectorised) and AVX2, dispatched at run time (off
//!   x86-64, and on x86-64 without AVX2, the portable kernel runs);
//! * [`features`]: integer sums → density, coherence, flow vector, 8-way label;
//! * [`appearance`]: per-block mean grey level and texture of a frame, measured a
//!   few times a second for the cascade's presence band;
//! * [`mask`]: camera mask polygons → block mask;
//! * [`pairing`]: which consecutive frames may be differenced (restarts, gaps);
//! * [`dis`]: the optional OpenCV DIS optical-flow backend, reduced to the same sums;
//! * [`eval`]: scoring blocks against annotated people (MOT ground truth);
//! * [`stage`]: the service's stage for the runtime (`frames` in, `motion` out);
//! * [`detector`]: all of it for one camera, with the global illumination check —
//!   what the service calls per frame, and what tests call without shared memory.
//!
//! ```
//! use isochron_motion::detector::MotionDetector;
//! use isochron_config::MotionConfig;
//! use isochron_wire::BlockMotion;
//!
//! let (w, h) = (64, 48);
//! let mut detector = MotionDetector::new(&MotionConfig::default(), w, h, &[]).unwrap();
//! let prev = vec![0u8; w * h];
//! let cur = vec![0u8; w * h];
//! let mut blocks = vec![BlockMotion::default(); detector.geometry().blocks()];
//! let report = detector.process(&prev, &cur, 0, &mut blocks).unwrap();
//! assert_eq!(report.moving_blocks, 0);
//! ```

pub mod appearance;
pub mod detector;
pub mod dis;
pub mod eval;
pub mod features;
pub mod kernel;
pub mod mask;
pub mod pairing;
pub mod stage;
