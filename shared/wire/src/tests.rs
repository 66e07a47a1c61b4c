use super::*;
use crate::geometry::BlockGrid;

fn cam() -> CameraId {
    CameraId::new("cam01").unwrap()
}

fn frame_header(w: u32, h: u32) -> FrameHeader {
    let mut preamble = Preamble::new::<u8>(Stream::Frames, cam(), 0, (w * h) as usize);
    preamble.capture_time_ns = 1;
    FrameHeader {
        preamble,
        width: w,
        height: h,
        stride: w,
        pixel_format: PixelFormat::Gray8 as u32,
        source_index: 0,
    }
}

#[test]
fn camera_ids() {
    assert_eq!(CameraId::new("cam-01_a").unwrap().as_str(), "cam-01_a");
    assert!(CameraId::new("").is_none());
    assert!(CameraId::new("has space").is_none());
    assert!(CameraId::new(&"x".repeat(25)).is_none());
    assert!(CameraId::new(&"x".repeat(24)).is_some());
}

#[test]
fn good_frame_header_validates() {
    assert_eq!(frame_header(64, 48).validate(&cam(), 64 * 48), Ok(()));
}

#[test]
fn wrong_magic_version_stream_camera_size_are_rejected() {
    let mut h = frame_header(64, 48);
    h.preamble.magic = 0xdead_beef;
    let err = h.validate(&cam(), 64 * 48).unwrap_err();
    assert!(matches!(err, WireError::Magic { .. }));
    assert!(err.to_string().contains("not an isochron service"));

    let mut h = frame_header(64, 48);
    h.preamble.layout_version = 99;
    assert!(matches!(
        h.validate(&cam(), 64 * 48),
        Err(WireError::Version { found: 99 })
    ));

    let mut h = frame_header(64, 48);
    h.preamble.stream = Stream::Motion as u16;
    assert!(matches!(
        h.validate(&cam(), 64 * 48),
        Err(WireError::Stream { .. })
    ));

    let h = frame_header(64, 48);
    let other = CameraId::new("cam02").unwrap();
    assert!(matches!(
        h.validate(&other, 64 * 48),
        Err(WireError::Camera { .. })
    ));

    // The header announces fewer bytes than the sample carries.
    let h = frame_header(64, 48);
    assert!(matches!(
        h.validate(&cam(), 64 * 48 + 1),
        Err(WireError::Size { .. })
    ));

    // Internally inconsistent: width*height does not fit the payload.
    let mut h = frame_header(64, 48);
    h.height = 50;
    let err = h.validate(&cam(), 64 * 48).unwrap_err();
    assert!(err.to_string().contains("frame size mismatch"), "{err}");
}

#[test]
fn motion_grid_must_follow_frame_size() {
    let mut preamble = Preamble::new::<BlockMotion>(Stream::Motion, cam(), 0, 48 * 36);
    preamble.capture_time_ns = 1;
    let mut h = MotionHeader {
        preamble,
        frame_width: 768,
        frame_height: 576,
        block_px: 16,
        grid_w: 48,
        grid_h: 36,
        changed_fraction: 0.0,
        source_index: 0,
    };
    assert_eq!(h.validate(&cam(), 48 * 36), Ok(()));
    h.grid_w = 47;
    assert!(h.validate(&cam(), 48 * 36).is_err());
}

#[test]
fn end_of_stream_needs_no_payload() {
    let mut h = frame_header(64, 48);
    h.preamble.payload_len = 0;
    h.preamble.flags = FLAG_END_OF_STREAM;
    assert_eq!(h.validate(&cam(), 0), Ok(()));
}

#[test]
fn a_grid_whose_product_wraps_in_u32_is_refused() {
    // 0xFFFFFFFF² wraps to 1 in u32 and 65 536² to 0: neither may pass as a
    // grid of 1 or 0 blocks.
    let wrapping = [
        [u32::MAX, u32::MAX, 1, u32::MAX, u32::MAX],
        [65_536 * 16, 65_536 * 16, 16, 65_536, 65_536],
    ];
    for (grid, blocks) in wrapping.into_iter().zip([1, 0]) {
        let mut p = Preamble::new::<BlockActivity>(Stream::Activity, cam(), 0, blocks);
        p.capture_time_ns = 1;
        let h = ActivityHeader {
            preamble: p,
            frame_width: grid[0],
            frame_height: grid[1],
            block_px: grid[2],
            grid_w: grid[3],
            grid_h: grid[4],
            ..Default::default()
        };
        let err = h.validate(&cam(), blocks).unwrap_err();
        assert!(err.to_string().contains("frame_width"), "{err}");
    }
    // The largest grid the bounds allow, and one block more.
    assert_eq!(check_block_grid([4096, 4096, 16, 256, 256]), Ok(MAX_BLOCKS));
    let err = check_block_grid([4096, 4112, 16, 256, 257]).unwrap_err();
    assert!(err.to_string().contains("at most 65536 blocks"), "{err}");
}

#[test]
fn a_known_grid_refuses_another() {
    let (a, b) = (BlockGrid::new(320, 240, 16), BlockGrid::new(640, 480, 16));
    let mut pinned = KnownGrid::new(None);
    assert_eq!(pinned.check(a), Ok(true));
    assert_eq!(pinned.check(a), Ok(false));
    let err = pinned.check(b).unwrap_err().to_string();
    assert!(
        err.contains("pinned by this camera's first sample"),
        "{err}"
    );
    let mut configured = KnownGrid::new(Some(b));
    assert_eq!(configured.check(b), Ok(false));
    let err = configured.check(a).unwrap_err().to_string();
    assert!(err.contains("camera.width/height"), "{err}");
}

fn event_header(phase: EventPhase, start_ns: i64, end_ns: i64) -> EventHeader {
    let mut preamble = Preamble::new::<u32>(Stream::Events, cam(), 0, 1);
    preamble.capture_time_ns = 1;
    EventHeader {
        preamble,
        kind: ActivityKind::Moving as u32,
        phase: phase as u32,
        start_ns,
        end_ns,
        ..Default::default()
    }
}

#[test]
fn an_event_that_ends_before_it_starts_is_refused() {
    assert_eq!(
        event_header(EventPhase::End, 10, 20).validate(&cam(), 1),
        Ok(())
    );
    assert_eq!(
        event_header(EventPhase::Start, 10, 0).validate(&cam(), 1),
        Ok(())
    );
    for (phase, start, end) in [
        (EventPhase::End, 20, 10),
        (EventPhase::Start, 10, 5),
        (EventPhase::End, -5, 10),
    ] {
        let err = event_header(phase, start, end).validate(&cam(), 1);
        assert!(matches!(err, Err(WireError::Field { .. })), "{err:?}");
    }
    let mut nan = event_header(EventPhase::End, 10, 20);
    nan.peak = f32::NAN;
    assert!(nan.validate(&cam(), 1).is_err());
}

#[test]
fn a_detection_region_past_the_largest_frame_is_refused() {
    let mut h = DetectionHeader {
        preamble: Preamble::new::<Detection>(Stream::Detections, cam(), 0, 1),
        roi_x: u32::MAX,
        roi_w: 1,
        roi_h: 1,
        ..Default::default()
    };
    assert!(h.validate(&cam(), 1).is_err());
    assert!(!h.searched(0.0, 0.0), "no overflow");
    (h.roi_x, h.roi_w) = (100, 50);
    assert_eq!(h.validate(&cam(), 1), Ok(()));
    h.preamble.payload_len = MAX_DETECTIONS as u32 + 1;
    assert!(h.validate(&cam(), MAX_DETECTIONS + 1).is_err());
}

/// A header of type `H` read from arbitrary bytes, as a foreign producer could
/// lay it out (every field of these types takes any bit pattern).
fn from_bytes<H: Copy>(bytes: &[u8]) -> H {
    assert!(bytes.len() >= std::mem::size_of::<H>());
    // SAFETY: the headers are `repr(C)` of integers, floats and byte arrays,
    // for which every bit pattern is a value; the read is unaligned-safe.
    unsafe { std::ptr::read_unaligned(bytes.as_ptr().cast::<H>()) }
}

/// Sizes as a forger picks them: the edges of every range, and anything.
fn size() -> impl proptest::strategy::Strategy<Value = u32> {
    use proptest::prelude::*;
    prop_oneof![
        Just(0u32),
        Just(1),
        Just(MAX_FRAME_SIDE),
        Just(MAX_FRAME_SIDE + 1),
        Just(65_536),
        Just(u32::MAX),
        0u32..=300,
        any::<u32>(),
    ]
}

mod properties {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]

        /// Any grid a header claims: validation never panics, and what it
        /// accepts is a grid of at most MAX_BLOCKS blocks that the payload
        /// matches, whose block count the grid itself computes without overflow.
        #[test]
        fn block_headers_accept_only_bounded_consistent_grids(
            fw in size(), fh in size(), px in size(), gw in size(), gh in size(),
            blocks in prop_oneof![Just(0usize), Just(1), 0usize..=70_000],
        ) {
            let mut p = Preamble::new::<BlockActivity>(Stream::Activity, cam(), 0, blocks);
            p.capture_time_ns = 1;
            let h = ActivityHeader {
                preamble: p,
                frame_width: fw,
                frame_height: fh,
                block_px: px,
                grid_w: gw,
                grid_h: gh,
                ..Default::default()
            };
            if h.validate(&cam(), blocks).is_ok() {
                let grid = h.block_grid();
                prop_assert!(grid.len() <= MAX_BLOCKS);
                prop_assert_eq!(grid.len(), blocks);
                prop_assert_eq!((grid.grid_w(), grid.grid_h()), (gw, gh));
            }
            let mut m = MotionHeader {
                preamble: Preamble::new::<BlockMotion>(Stream::Motion, cam(), 0, blocks),
                frame_width: fw,
                frame_height: fh,
                block_px: px,
                grid_w: gw,
                grid_h: gh,
                changed_fraction: 0.0,
                source_index: 0,
            };
            m.preamble.capture_time_ns = 1;
            if m.validate(&cam(), blocks).is_ok() {
                prop_assert!(m.block_grid().len() == blocks && blocks <= MAX_BLOCKS);
            }
        }

        /// Headers of arbitrary bytes (a foreign or hostile producer) with the
        /// right magic, version and camera: validation never panics; an
        /// accepted one is consistent with its payload.
        #[test]
        fn arbitrary_headers_never_panic(
            bytes in proptest::collection::vec(any::<u8>(), 512),
            len in prop_oneof![Just(0usize), Just(1), 0usize..=100_000],
            stream in 1u16..=5,
        ) {
            let fix = |p: &mut Preamble| {
                p.magic = MAGIC;
                p.layout_version = LAYOUT_VERSION;
                p.stream = stream;
                p.camera = cam();
                p.payload_len = len as u32;
            };
            let mut a: ActivityHeader = from_bytes(&bytes);
            fix(&mut a.preamble);
            a.preamble.element_size = std::mem::size_of::<BlockActivity>() as u32;
            if a.validate(&cam(), len).is_ok() && !a.preamble.is_end_of_stream() {
                prop_assert_eq!(a.block_grid().len(), len);
            }
            let mut m: MotionHeader = from_bytes(&bytes);
            fix(&mut m.preamble);
            m.preamble.element_size = std::mem::size_of::<BlockMotion>() as u32;
            if m.validate(&cam(), len).is_ok() && !m.preamble.is_end_of_stream() {
                prop_assert_eq!(m.block_grid().len(), len);
            }
            let mut e: EventHeader = from_bytes(&bytes);
            fix(&mut e.preamble);
            e.preamble.element_size = 4;
            if e.validate(&cam(), len).is_ok() && !e.preamble.is_end_of_stream() {
                prop_assert!(len <= MAX_BLOCKS);
                prop_assert!(e.phase != EventPhase::End as u32 || e.end_ns >= e.start_ns);
            }
            let mut d: DetectionHeader = from_bytes(&bytes);
            fix(&mut d.preamble);
            d.preamble.element_size = std::mem::size_of::<Detection>() as u32;
            if d.validate(&cam(), len).is_ok() && !d.preamble.is_end_of_stream() {
                prop_assert!(len <= MAX_DETECTIONS);
            }
            d.searched(f32::MAX, f32::MIN);
            let mut f: FrameHeader = from_bytes(&bytes);
            fix(&mut f.preamble);
            f.preamble.element_size = 1;
            if f.validate(&cam(), len).is_ok() && !f.preamble.is_end_of_stream() {
                prop_assert_eq!(f.stride as usize * f.height as usize, len);
            }
        }
    }
}

#[test]
fn fixed_strings_round_trip() {
    let z: [u8; ZONE_NAME_LEN] = to_fixed("entrance");
    assert_eq!(fixed_str(&z), "entrance");
    let long: [u8; 4] = to_fixed("héllo");
    assert_eq!(fixed_str(&long), "hél");
    // Never cut a character in half.
    let cut: [u8; 2] = to_fixed("hé");
    assert_eq!(fixed_str(&cut), "h");
}
