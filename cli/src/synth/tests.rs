use super::crowd::direction_label;
use super::*;
use isochron_wire::DIRECTION_NONE;

#[test]
fn profiles_parse_and_interpolate_around_midnight() {
    let p = Profile::parse("minute_of_day,activity\n0,0\n600,1\n720,0.5\n1380,0.2\n").unwrap();
    assert_eq!(p.at(0.0), 0.0);
    assert_eq!(p.at(300.0), 0.5);
    assert_eq!(p.at(600.0), 1.0);
    assert!((p.at(660.0) - 0.75).abs() < 1e-12);
    // Between 23:00 (0.2) and midnight (0).
    assert!((p.at(1410.0) - 0.1).abs() < 1e-12);
    assert!((p.at(1440.0 + 300.0) - 0.5).abs() < 1e-12);
    let one = Profile::parse("5,0.3").unwrap();
    assert_eq!(one.at(1000.0), 0.3);
    for bad in [
        "",
        "minute,activity\n",
        "0,2\n",
        "1500,0.1\n",
        "0,x\n",
        "0\n",
    ] {
        assert!(Profile::parse(bad).is_err(), "{bad:?}");
    }
    let err = Profile::parse("0,0.1\n10,1.5\n").unwrap_err();
    assert!(err.to_string().contains("line 2"), "{err}");
}

#[test]
fn arguments_parse() {
    assert_eq!(parse_grid("16x12").unwrap(), (16, 12));
    assert!(parse_grid("16").is_err() && parse_grid("0x3").is_err());
    assert_eq!(
        parse_start("2026-01-05").unwrap(),
        parse_rfc3339("2026-01-05T00:00:00Z").unwrap()
    );
    assert_eq!(
        parse_start("2026-01-05T06:00:00+01:00").unwrap(),
        parse_rfc3339("2026-01-05T05:00:00Z").unwrap()
    );
    assert!(parse_start("monday").is_err());
    assert_eq!(direction_label(1.0, 0.0), 0);
    assert_eq!(direction_label(0.0, -1.0), 2);
    assert_eq!(direction_label(-1.0, 0.0), 4);
    assert_eq!(direction_label(0.0, 1.0), 6);
    assert_eq!(direction_label(0.0, 0.0), DIRECTION_NONE);
}

#[test]
fn arrivals_follow_the_profile() {
    let mut s = Synth::new(16, 12, 2.0, 7, 30.0, 0.0);
    let mut blocks = vec![BlockMotion::default(); 192];
    let mut busy = 0;
    for _ in 0..(2 * 3600) {
        busy += s.frame(1.0, &mut blocks);
    }
    let mut quiet = 0;
    for _ in 0..(2 * 3600) {
        quiet += s.frame(0.25, &mut blocks);
    }
    // A quarter of the arrivals: a quarter of the motion, within noise.
    let ratio = quiet as f64 / busy as f64;
    assert!((ratio - 0.25).abs() < 0.05, "{ratio}");
    // People move in straight lines: every block with motion has a direction.
    assert!(
        blocks
            .iter()
            .all(|b| b.density == 0.0 || b.direction != DIRECTION_NONE)
    );
    let mut idle = Synth::new(16, 12, 2.0, 7, 30.0, 0.0);
    for _ in 0..100 {
        assert_eq!(idle.frame(0.0, &mut blocks), 0);
    }
    assert!(blocks.iter().all(|b| b.density == 0.0));
}
