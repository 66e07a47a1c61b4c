//! Unit tests of the configuration reference's generator: stated defaults, names.

use super::*;

#[test]
fn literal_defaults_in_prose_are_found_and_others_are_not() {
    let found = stated_defaults(
        "Block edge. Default 16. Default `false` (live). Default `\"UTC\"`. Default true: x. \
         Default 1800 (30 min). Default: `cap` (98). default: measured. Default none.",
    );
    let shown: Vec<&str> = found.iter().map(Stated::raw).collect();
    assert_eq!(shown, ["16", "`false`", "`\"UTC\"`", "true", "1800"]);
    assert!(matches!(found[2], Stated::Text(ref t, _) if t == "UTC"));
    assert!(matches!(found[4], Stated::Number(n, _) if n == 1800.0));
}

#[test]
fn a_stated_default_must_be_the_real_one_and_a_bare_one_is_dropped() {
    let (cell, doc) = default_cell(
        "motion.block_px",
        "motion.rs",
        "Block edge in pixels. Default 16.",
        false,
        false,
        Some(&Value::from(16)),
    )
    .unwrap();
    assert_eq!(
        (cell.as_str(), doc.as_str()),
        ("`16`", "Block edge in pixels.")
    );
    let wrong = default_cell(
        "k",
        "f.rs",
        "Default 32.",
        false,
        false,
        Some(&Value::from(16)),
    );
    assert!(
        wrong
            .unwrap_err()
            .to_string()
            .contains("the default is 32 but it is 16")
    );
    let unset = default_cell("k", "f.rs", "Default 0.1.", false, true, Some(&Value::Null));
    assert_eq!(unset.unwrap(), ("unset".into(), "Default 0.1.".into()));
}

#[test]
fn names_follow_serde_and_github() {
    assert_eq!(rename("MotionFlow", Some("kebab-case")), "motion-flow");
    assert_eq!(rename("Daily", Some("lowercase")), "daily");
    assert_eq!(strip_section_prefix("`[site]`: settings."), "Settings.");
    assert_eq!(anchor("[[camera.floor_points]]"), "camerafloor_points");
}
