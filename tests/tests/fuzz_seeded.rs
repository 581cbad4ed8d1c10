//! A short, seeded run of the mutation fuzzer (`softhaptic_tests::fuzz`) over every parser that
//! takes outside input: the same inputs on every run, so a failure here reproduces with
//! `fuzz-report --target NAME --seed 7 --inputs N`. The offline report runs millions; this keeps
//! a parser change that brings back a panic from passing the test suite. The counts keep the
//! file within seconds in a debug build: loading a scene builds its mesh, and a recording is a
//! quarter of a megabyte, so those two run fewer inputs.

#![allow(clippy::unwrap_used)] // test code: a panic is how a failure is reported

use softhaptic_tests::fuzz::{self, Target};

// Each input is held to its target's memory limit (a crash when it goes past): this counts.
#[global_allocator]
static ALLOCATOR: fuzz::CountingAllocator = fuzz::CountingAllocator;

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
    assert!(fuzz::memory_is_counted(), "the memory limits count nothing");
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

/// A recording padded to decode to 200 MiB (four contact frames of 50 MiB of whitespace, 140 KB
/// on disk) is refused within the recordings' memory limit: the reader once held all of it.
#[test]
fn a_recording_padded_to_decode_to_hundreds_of_mib_is_refused_within_the_memory_limit() {
    let target = target("mcap");
    let dir = softhaptic_tests::scratch_dir("fuzz-padded");
    let path = dir.join("padded.mcap");
    softhaptic_tests::crafted::padded_recording(&path, 4, 50 << 20);
    let input = std::fs::read(&path).unwrap();
    let _ = std::fs::remove_dir_all(&dir);
    let (outcome, peak) = fuzz::run_measured(&target, &input);
    match outcome {
        Ok(fuzz::Outcome::Refused(e)) => assert!(e.contains("more than the limit of"), "{e}"),
        other => panic!("{other:?}"),
    }
    assert!(fuzz::memory_is_counted());
    assert!(peak < 64 << 20, "{} MiB", peak >> 20);
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

/// Parses OBJ text as the server does, naming it `<test>.obj` in errors.
fn parse_obj(text: &str) -> Result<softhaptic_device::mesh::HapticMesh, String> {
    softhaptic_server::scene::parse_obj(
        text,
        std::path::Path::new("<test>.obj"),
        std::path::Path::new("<test>"),
        "object.haptic_mesh",
    )
    .map_err(|e| e.to_string())
}

const TRIANGLE: &str = "v 0 0 0\nv 0.01 0 0\nv 0 0.01 0\nvt 0 0\nvn 0 0 1\n";

/// Found by the fuzzer: the OBJ reader multiplied a texture-coordinate or normal index before
/// checking it, so an index reaching before the first `vt`/`vn` line, or a huge one, overflowed
/// (a panic in a build with overflow checks).
#[test]
fn an_obj_face_with_a_texture_or_normal_index_out_of_range_is_refused_not_a_panic() {
    for face in [
        "f 1/-9 2/1 3/1",
        "f 1//-2 2//1 3//1",
        "f 1/1/9223372036854775807 2/1/1 3/1/1",
        "f 1/4611686018427387904 2/1 3/1",
        "l 1/-3 2/1",
        "p 1/1/-7",
    ] {
        let reason = parse_obj(&format!("{TRIANGLE}{face}\n")).unwrap_err();
        assert!(
            reason.contains("line 6") && reason.contains("the file has 1"),
            "{face}: {reason}"
        );
    }
}

#[test]
fn an_obj_face_with_texture_and_normal_indices_in_range_still_loads() {
    for face in [
        "f 1/1/1 2/1/1 3/1/1",
        "f -3/-1/-1 -2/-1/-1 -1/-1/-1",
        "f 1//1 2//1 3//1",
        "f 1/0 2/0 3/0",
    ] {
        let mesh = parse_obj(&format!("{TRIANGLE}{face}\n")).unwrap();
        assert_eq!(mesh.triangles().len(), 1, "{face}");
    }
}
