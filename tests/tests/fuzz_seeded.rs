//! A short, seeded run of the mutation fuzzer (`softhaptic_tests::fuzz`) over every parser that
//! takes outside input: the same inputs on every run, so a failure here reproduces with
//! `fuzz-report --target NAME --seed 7 --inputs N`. The offline report runs millions; this keeps
//! a parser change that brings back a panic from passing the test suite. The counts keep the
//! file within seconds in a debug build: loading a scene builds its mesh, and a recording is a
//! quarter of a megabyte, so those two run fewer inputs.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use softhaptic_tests::fuzz::{self, Target};

const SEED: u64 = 7;

fn target(name: &str) -> Target {
    fuzz::targets(&fuzz::repo_root())
        .unwrap()
        .into_iter()
        .find(|t| t.name == name)
        .unwrap()
}

/// Runs `count` inputs and fails naming every panic and the file it was saved to.
fn no_input_panics(name: &str, count: u64) {
    let target = target(name);
    let crash_dir = std::env::temp_dir().join("softhaptic-fuzz-seeded");
    let stats = fuzz::run(&target, SEED, 0, count, &crash_dir, |_| true);
    assert_eq!(stats.inputs, count);
    let crashes: Vec<String> = stats
        .crashes
        .iter()
        .map(|c| format!("input {}: {} (saved as {:?})", c.index, c.message, c.saved))
        .collect();
    assert!(crashes.is_empty(), "{name}: {crashes:#?}");
    // Mutations that never reach past the first byte's check would prove nothing.
    assert!(
        stats.accepted > 0 && stats.refused > 0,
        "{name}: {} accepted, {} refused: the mutations should produce both",
        stats.accepted,
        stats.refused
    );
}

#[test]
fn mutated_scene_files_are_refused_or_loaded_without_a_panic() {
    no_input_panics("scene", 150);
}

#[test]
fn mutated_obj_meshes_are_refused_or_get_a_collider_without_a_panic() {
    no_input_panics("obj", 3000);
}

#[test]
fn mutated_calibration_tables_are_refused_or_answer_every_depth_without_a_panic() {
    no_input_panics("calibration", 3000);
}

#[test]
fn mutated_limits_files_are_refused_or_validated_without_a_panic() {
    no_input_panics("limits", 2000);
}

#[test]
fn mutated_recordings_are_refused_or_summarised_without_a_panic() {
    no_input_panics("mcap", 60);
}

#[test]
fn mutated_wire_messages_are_refused_or_decoded_on_both_sides_without_a_panic() {
    no_input_panics("wire", 5000);
}

#[test]
fn the_same_seed_and_index_make_the_same_input() {
    let target = target("wire");
    let inputs: Vec<Vec<u8>> = (0..50)
        .map(|i| fuzz::make_input(&target, SEED, i))
        .collect();
    let again: Vec<Vec<u8>> = (0..50)
        .map(|i| fuzz::make_input(&target, SEED, i))
        .collect();
    assert_eq!(inputs, again);
    // And the mutator changes something: not every input is a seed as it was.
    assert!(inputs.iter().any(|i| !target.seeds.contains(i)));
}
