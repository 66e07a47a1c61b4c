//! The reference implementations the tests meet: the Python venv and the npm
//! packages `cargo xtask setup --all` installs.

use std::path::PathBuf;
use std::process::Command;

use crate::setup_file;

/// The Python of the test venv (`target/ros2-venv`, made by `cargo xtask setup --all`),
/// checked to import `modules` (a Python import list); fails saying what to do.
pub fn venv_python(modules: &str) -> PathBuf {
    let path = setup_file(
        "ISOCHRON_ROS2_PYTHON",
        "target/ros2-venv/bin/python3",
        &format!("(it makes a Python venv with the test peers' packages: {modules})"),
    );
    let ok = Command::new(&path)
        .args(["-c", &format!("import {modules}")])
        .status()
        .is_ok_and(|s| s.success());
    assert!(
        ok,
        "{} cannot import {modules}: run `cargo xtask setup --all` again",
        path.display()
    );
    path
}

/// The `node_modules` of the npm test peers (`target/node-peers`, which `cargo
/// xtask setup` installs from `tests/view/package.json`), for `NODE_PATH`; fails
/// saying what to do when they are missing.
pub fn node_modules() -> PathBuf {
    let package = setup_file(
        "ISOCHRON_NODE_PEERS",
        "target/node-peers/node_modules/@foxglove/ws-protocol/package.json",
        "(it installs the npm test peers: @foxglove/ws-protocol, ws, protobufjs)",
    );
    package
        .ancestors()
        .nth(3)
        .expect("node_modules/@foxglove/ws-protocol/package.json")
        .to_path_buf()
}
