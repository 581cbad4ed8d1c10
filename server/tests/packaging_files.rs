//! The package's files agree with the code and with each other (packaging/, docs/install.md):
//! the udev rules grant the SpaceMouse exactly as the rule the binary prints when it cannot read
//! a device, to groups the station's unit joins; the settings name an installed scene, which
//! loads from the installed layout (scenes/ with calibration/ beside it); the tmpfiles
//! directories are the ones the units write to. The built package itself is tested by
//! web/tests/package.test.mjs.

#![allow(clippy::disallowed_methods)] // test code: reads the source tree's packaging files
#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use std::path::{Path, PathBuf};

fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(path)
}

fn read(path: &str) -> String {
    std::fs::read_to_string(repo(path)).unwrap()
}

/// `Key=value` of a unit (continuation lines joined; the last one of a key wins, as systemd's).
fn unit_value(unit: &str, key: &str) -> String {
    let joined = unit.replace("\\\n", " ");
    joined
        .lines()
        .filter_map(|l| l.trim().split_once('='))
        .filter(|(k, _)| k.trim() == key)
        .map(|(_, v)| v.trim().to_owned())
        .next_back()
        .unwrap_or_else(|| panic!("the unit sets no {key}"))
}

#[test]
fn the_udev_rules_grant_the_devices_to_the_groups_the_station_joins() {
    let rules = read("packaging/70-softhaptic.rules");
    // The SpaceMouse's rule is the one `softhaptic devices` and the doctor print.
    for line in softhaptic_device::spacemouse::hid::UDEV_RULE.lines() {
        assert!(
            rules.lines().any(|l| l == line),
            "packaging/70-softhaptic.rules lacks the code's rule {line}"
        );
    }
    let unit = read("packaging/debian/softhaptic.softhaptic-station.service");
    let groups = unit_value(&unit, "SupplementaryGroups");
    let groups: Vec<&str> = groups.split_whitespace().collect();
    let rule_lines: Vec<&str> = rules
        .lines()
        .filter(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .collect();
    assert!(rule_lines.len() >= 3, "{rule_lines:?}");
    for line in rule_lines {
        let group = line
            .split(", ")
            .find_map(|part| part.strip_prefix("GROUP=\""))
            .and_then(|g| g.strip_suffix('"'))
            .unwrap_or_else(|| panic!("a rule without GROUP: {line}"));
        assert!(
            groups.contains(&group),
            "the rule's group {group} is not among the station's {groups:?}"
        );
        assert!(line.contains("MODE=\"0660\""), "{line}");
    }
}

#[test]
fn the_settings_name_an_installed_scene_that_loads_from_the_installed_layout() {
    let conf = read("packaging/station.conf");
    let scene = conf
        .lines()
        .find_map(|l| l.strip_prefix("SOFTHAPTIC_SCENE="))
        .unwrap()
        .trim();
    // Installed as /usr/share/softhaptic/scenes/<scene> with calibration/ beside it: the very
    // layout of the source tree's scenes/, so the source tree's copy loads as the installed one.
    let path = repo("scenes").join(scene);
    softhaptic_server::scene::Scene::load(&path)
        .unwrap_or_else(|e| panic!("station.conf's scene {scene}: {e}"));
}

#[test]
fn the_directories_the_units_write_are_made_with_the_modes_a_secret_needs() {
    let tmpfiles = read("packaging/softhaptic.tmpfiles");
    let entries: Vec<Vec<&str>> = tmpfiles
        .lines()
        .filter(|l| !l.trim().is_empty() && !l.starts_with('#'))
        .map(|l| l.split_whitespace().collect())
        .collect();
    let mode_of = |dir: &str| {
        entries
            .iter()
            .find(|e| e[1] == dir)
            .map(|e| (e[2], e[3], e[4]))
            .unwrap_or_else(|| panic!("tmpfiles.d makes no {dir}"))
    };
    assert_eq!(mode_of("/etc/softhaptic"), ("0750", "root", "softhaptic"));
    assert_eq!(
        mode_of("/etc/softhaptic/tls"),
        ("0700", "softhaptic", "softhaptic")
    );
    for unit in [
        "packaging/debian/softhaptic.softhaptic-station.service",
        "packaging/debian/softhaptic.softhaptic-hub.service",
    ] {
        let unit = read(unit);
        assert_eq!(unit_value(&unit, "User"), "softhaptic");
        assert_eq!(unit_value(&unit, "UMask"), "0077");
        let exec = unit_value(&unit, "ExecStart");
        let words: Vec<&str> = exec.split_whitespace().collect();
        let after = |flag: &str| {
            words
                .windows(2)
                .find(|w| w[0] == flag)
                .map(|w| w[1])
                .unwrap_or_else(|| panic!("{exec}: no {flag}"))
        };
        assert_eq!(after("--token-file"), "/etc/softhaptic/tokens");
        // The self-signed certificate is made where the unit may write and no one else reads.
        let data = after("--data-dir");
        assert_eq!(mode_of(data).0, "0700");
        assert_eq!(unit_value(&unit, "ReadWritePaths"), format!("-{data}"));
        if let Some(w) = words.windows(2).find(|w| w[0] == "--record-dir") {
            assert_eq!(mode_of(w[1]), ("0750", "softhaptic", "softhaptic"));
            assert!(w[1].starts_with(&format!(
                "/var/lib/{}/",
                unit_value(&unit, "StateDirectory")
            )));
        }
    }
    // The sysusers.d file makes the user the units run as.
    assert!(
        read("packaging/softhaptic.sysusers")
            .lines()
            .any(|l| l.starts_with("u softhaptic ")),
    );
}
