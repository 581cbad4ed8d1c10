//! A mutation fuzzer for every parser that takes outside input, on stable Rust.
//!
//! Long because every target, its seeds and its format-aware mutations are listed here, so that
//! fuzzing a new parser is one entry in one file.
//!
//! cargo-fuzz needs a nightly toolchain; this is the equivalent the project can always run. Each
//! [`Target`] is the real parser (and what the server does next with what it accepted) behind a
//! function of `&[u8]`, with a corpus of valid seeds taken from the repository. An input is a
//! seed changed by a few mutations drawn from a generator seeded by `(seed, target, index)`
//! alone, so input number `index` can be rebuilt without replaying the ones before it: a run
//! that dies of something `catch_unwind` cannot catch (an abort, a stack overflow) is reproduced
//! from the index its progress last printed. There is no coverage feedback (that is what a
//! nightly toolchain would add); the mutations make up for part of it by knowing the formats'
//! tokens: numbers replaced by extreme ones, brackets and quotes inserted, length fields of the
//! binary format overwritten by huge values.
//!
//! A panic is a failure, and so is an input that makes its parser hold more memory at once than
//! the target's limit ([`Target::max_memory_bytes`]: a parser that believes a length field, or
//! keeps what a crafted input decompresses to). [`run`] runs each input under
//! [`std::panic::catch_unwind`], measuring what it allocates with [`CountingAllocator`] (which the
//! fuzzer's programs install as their global allocator), and saves an input that failed under
//! the caller's directory, named by target and content hash, so it can be turned into a
//! regression test. The offline report (`src/bin/fuzz_report.rs`) runs
//! millions of inputs per target; `tests/fuzz_seeded.rs` runs a few thousand in the test suite.

use std::cell::RefCell;
use std::collections::{HashMap, HashSet};
use std::path::{Path, PathBuf};

use softhaptic_device::collision::{Collider, CollisionMode};
use softhaptic_proto::wire::ReplayControl;
use softhaptic_proto::wire::{self, Auth, ServerMessage};
use softhaptic_proto::{CalibrationTable, ModelLimitsFile, ModelSpec, ToolShape, ValidityLimits};
use softhaptic_server::scene::{self, Scene};
use softhaptic_server::session::reader::Recording;
use softhaptic_server::session::tools::Info;
use softhaptic_server::session::writer::SessionWriter;

/// What one input did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Outcome {
    /// The parser accepted it (and everything after the parse ran).
    Accepted,
    /// The parser refused it with this error message.
    Refused(String),
    /// Not an input this parser is ever given (non-UTF-8 text: the file reader refuses it first).
    Skipped,
}

/// One parser under test.
pub struct Target {
    /// Short name, used on the command line and in crash file names.
    pub name: &'static str,
    /// Extension of saved crash files, so an editor opens them as what they are.
    pub extension: &'static str,
    /// A text format: inputs are made valid UTF-8 (invalid sequences replaced) before the
    /// parser sees them, since the file reader refuses anything else and a skipped input tests
    /// nothing.
    pub text: bool,
    /// Valid inputs the mutations start from.
    pub seeds: Vec<Vec<u8>>,
    /// The parser and what follows it; it must return, never panic.
    pub run: fn(&[u8]) -> Outcome,
    /// The most memory one input may make it hold at once, bytes (counted by
    /// [`CountingAllocator`], on the thread that runs the input).
    pub max_memory_bytes: u64,
}

/// The memory limit of the text targets: a few times what the largest seed's scene, mesh or
/// table takes.
const TEXT_MEMORY_LIMIT: u64 = 256 << 20;
/// The recordings' limit: what the reader may decode from a small file (32 MiB), one chunk's
/// decompression in the walk and again in the MCAP library (at most 64 MiB each), and the
/// rest. A reader that kept what a crafted file decompresses to would go far past it.
const MCAP_MEMORY_LIMIT: u64 = 256 << 20;

/// The global allocator of the fuzzer's programs (`#[global_allocator] static A:
/// CountingAllocator = CountingAllocator;`): the system's, counting per thread the bytes
/// allocated and not yet freed, and the most at once, so that [`run_one`] knows what an input
/// cost. Counting is two thread-local integers per call, and never allocates.
pub struct CountingAllocator;

thread_local! {
    static LIVE_BYTES: std::cell::Cell<i64> = const { std::cell::Cell::new(0) };
    static PEAK_BYTES: std::cell::Cell<i64> = const { std::cell::Cell::new(0) };
}

/// Whether a [`CountingAllocator`] counted anything (it is the global allocator).
static COUNTING: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

fn count_allocation(delta: i64) {
    // `try_with`: a thread being torn down has no counters left; its frees are not counted.
    let _ = LIVE_BYTES.try_with(|live| {
        let now = live.get() + delta;
        live.set(now);
        let _ = PEAK_BYTES.try_with(|peak| peak.set(peak.get().max(now)));
    });
}

// SAFETY: every call is passed to the system allocator unchanged; the counting touches
// thread-local integers only and never allocates.
unsafe impl std::alloc::GlobalAlloc for CountingAllocator {
    unsafe fn alloc(&self, layout: std::alloc::Layout) -> *mut u8 {
        // SAFETY: the caller's contract is `GlobalAlloc::alloc`'s, passed on.
        let p = unsafe { std::alloc::System.alloc(layout) };
        if !p.is_null() {
            count_allocation(layout.size() as i64);
        }
        p
    }
    unsafe fn alloc_zeroed(&self, layout: std::alloc::Layout) -> *mut u8 {
        // SAFETY: as for `alloc`.
        let p = unsafe { std::alloc::System.alloc_zeroed(layout) };
        if !p.is_null() {
            count_allocation(layout.size() as i64);
        }
        p
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: std::alloc::Layout) {
        // SAFETY: `ptr` was allocated by `System` with `layout` (every allocation goes there).
        unsafe { std::alloc::System.dealloc(ptr, layout) };
        count_allocation(-(layout.size() as i64));
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: std::alloc::Layout, new_size: usize) -> *mut u8 {
        // SAFETY: as for `dealloc`, and the caller's contract for `new_size`.
        let p = unsafe { std::alloc::System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            count_allocation(new_size as i64 - layout.size() as i64);
        }
        p
    }
}

/// Starts measuring this thread's peak from what it holds now; [`CountingAllocator`] only.
fn start_measuring() -> i64 {
    let live = LIVE_BYTES.with(std::cell::Cell::get);
    PEAK_BYTES.with(|peak| peak.set(live));
    live
}

/// The most this thread held at once since `start_measuring` returned `from`, bytes.
fn measured_peak(from: i64) -> u64 {
    let peak = PEAK_BYTES.with(std::cell::Cell::get);
    if peak > 0 {
        COUNTING.store(true, std::sync::atomic::Ordering::Relaxed);
    }
    (peak - from).max(0) as u64
}

/// Whether the program's global allocator is a [`CountingAllocator`] (known once an input ran):
/// without it the memory limits check nothing.
pub fn memory_is_counted() -> bool {
    COUNTING.load(std::sync::atomic::Ordering::Relaxed)
}

/// The names of every target, in the order [`targets`] returns them.
pub const TARGET_NAMES: [&str; 6] = ["scene", "obj", "calibration", "limits", "mcap", "wire"];

/// The repository's root (this crate's parent directory).
pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .map(Path::to_path_buf)
        .unwrap_or_else(|| PathBuf::from(".."))
}

/// Every target with its seeds read from the repository at `root`.
pub fn targets(root: &Path) -> Result<Vec<Target>, String> {
    Ok(vec![
        Target {
            name: "scene",
            extension: "toml",
            text: true,
            seeds: files_with_extension(&root.join("scenes"), "toml")?,
            run: scene_toml,
            max_memory_bytes: TEXT_MEMORY_LIMIT,
        },
        Target {
            name: "obj",
            extension: "obj",
            text: true,
            seeds: obj_seeds(root)?,
            run: obj,
            max_memory_bytes: TEXT_MEMORY_LIMIT,
        },
        Target {
            name: "calibration",
            extension: "json",
            text: true,
            seeds: calibration_seeds(root)?,
            run: calibration_json,
            max_memory_bytes: TEXT_MEMORY_LIMIT,
        },
        Target {
            name: "limits",
            extension: "json",
            text: true,
            seeds: vec![read(&root.join("scenes/calibration/model_limits.json"))?],
            run: limits_json,
            max_memory_bytes: TEXT_MEMORY_LIMIT,
        },
        Target {
            name: "mcap",
            extension: "mcap",
            text: false,
            seeds: mcap_seeds(root)?,
            run: mcap,
            max_memory_bytes: MCAP_MEMORY_LIMIT,
        },
        Target {
            name: "wire",
            extension: "json",
            text: true,
            seeds: wire_seeds(root)?,
            run: wire_messages,
            max_memory_bytes: TEXT_MEMORY_LIMIT,
        },
    ])
}

// ---------------------------------------------------------------------------------------------
// The targets.

/// A scene file loaded as a built-in scene (no base directory: it cannot read files), then the
/// haptic world the server builds from it (the collider's BVH, the curvature when asked for).
fn scene_toml(bytes: &[u8]) -> Outcome {
    let Ok(text) = std::str::from_utf8(bytes) else {
        return Outcome::Skipped;
    };
    match Scene::from_toml(text, Path::new("<fuzz>"), None) {
        Ok(scene) => {
            let _world = scene.haptic_world_with(collider_for(&scene));
            let _info = scene.contact_model_info();
            Outcome::Accepted
        }
        Err(e) => Outcome::Refused(e.to_string()),
    }
}

/// Colliders already built, by [`collider_key`]; cleared when full.
const MAX_CACHED_COLLIDERS: usize = 64;

thread_local! {
    static COLLIDERS: RefCell<HashMap<u64, Collider>> = RefCell::new(HashMap::new());
    static COLLIDER_BUILDS: std::cell::Cell<u64> = const { std::cell::Cell::new(0) };
}

/// How many colliders the scene target has built (rather than cloned) on this thread: the
/// distinct (mesh, collision mode, curvature) inputs it gave the BVH builder.
pub fn scene_collider_builds() -> u64 {
    COLLIDER_BUILDS.with(std::cell::Cell::get)
}

/// The scene's collider, built only when no earlier input gave the builder the same mesh, mode
/// and curvature request. The build (BVH, curvature) is a function of those alone, and nine in
/// ten accepted scenes change only numbers the build never reads while the liver's build costs
/// about 8 ms: building it again would spend the run on inputs already tried.
fn collider_for(scene: &Scene) -> Collider {
    let curvature = scene.contact_model.spec().curvature;
    let key = collider_key(scene, curvature);
    if let Some(collider) = COLLIDERS.with(|c| c.borrow().get(&key).cloned()) {
        return collider;
    }
    let mut collider = Collider::new(scene.haptic_mesh.clone(), scene.collision);
    if curvature {
        collider = collider.with_curvature();
    }
    COLLIDER_BUILDS.with(|n| n.set(n.get() + 1));
    COLLIDERS.with(|c| {
        let mut c = c.borrow_mut();
        if c.len() >= MAX_CACHED_COLLIDERS {
            c.clear();
        }
        c.insert(key, collider.clone());
    });
    collider
}

/// A 64-bit hash of everything [`Collider::new`] and [`Collider::with_curvature`] read.
fn collider_key(scene: &Scene, curvature: bool) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut hasher = std::collections::hash_map::DefaultHasher::new();
    let positions: Vec<[u64; 3]> = (scene.haptic_mesh.positions_m().iter())
        .map(|p| p.to_array().map(f64::to_bits))
        .collect();
    positions.hash(&mut hasher);
    scene.haptic_mesh.triangles().hash(&mut hasher);
    format!("{:?}", scene.collision).hash(&mut hasher);
    curvature.hash(&mut hasher);
    hasher.finish()
}

/// OBJ text through the server's reader, then the collider's BVH over the mesh (where a mesh
/// with coordinates beyond f32's range used to panic).
fn obj(bytes: &[u8]) -> Outcome {
    let Ok(text) = std::str::from_utf8(bytes) else {
        return Outcome::Skipped;
    };
    match scene::parse_obj(text, Path::new("<fuzz>.obj"), Path::new("<fuzz>"), "mesh") {
        Ok(mesh) => {
            let _collider = Collider::new(mesh, CollisionMode::Continuous);
            Outcome::Accepted
        }
        Err(e) => Outcome::Refused(e.to_string()),
    }
}

/// Depths the server may ask a table about: in range, at zero, negative, far beyond the table,
/// and not numbers at all.
const QUERY_DEPTHS_M: [f64; 10] = [
    0.0,
    -1e-3,
    1e-4,
    3e-3,
    0.006,
    0.02,
    1e308,
    f64::MAX,
    f64::NAN,
    f64::INFINITY,
];

/// A calibration table as serde validates it, then every query the server makes of one (the
/// deformed radius in each frame, the table sent in the `scene` message).
fn calibration_json(bytes: &[u8]) -> Outcome {
    let Ok(text) = std::str::from_utf8(bytes) else {
        return Outcome::Skipped;
    };
    match serde_json::from_str::<CalibrationTable>(text) {
        Ok(table) => {
            for depth_m in QUERY_DEPTHS_M.into_iter().chain([-f64::INFINITY]) {
                std::hint::black_box(table.deformed_radius_m(depth_m));
            }
            std::hint::black_box((table.threshold_m(), table.block_m(), table.description()));
            std::hint::black_box(serde_json::to_string(&table).is_ok());
            Outcome::Accepted
        }
        Err(e) => Outcome::Refused(e.to_string()),
    }
}

/// The tools the limits are looked up for: the shipped scenes' and a few odd ones.
fn lookup_tools() -> [ToolShape; 3] {
    [
        ToolShape::Sphere { radius_m: 0.01 },
        ToolShape::Cone {
            half_angle_rad: std::f64::consts::FRAC_PI_4,
            radius_m: 0.01,
        },
        ToolShape::Sphere { radius_m: 1e-300 },
    ]
}

/// A model-limits file, the check the scene loader applies, then the lookup it makes.
fn limits_json(bytes: &[u8]) -> Outcome {
    let Ok(text) = std::str::from_utf8(bytes) else {
        return Outcome::Skipped;
    };
    let file = match serde_json::from_str::<ModelLimitsFile>(text) {
        Ok(file) => file,
        Err(e) => return Outcome::Refused(e.to_string()),
    };
    if let Err(reason) = scene::validate_limits(&file) {
        return Outcome::Refused(reason);
    }
    for tool in lookup_tools() {
        std::hint::black_box(ValidityLimits::of(Some(&file), &tool, &ModelSpec::PAPER));
    }
    Outcome::Accepted
}

/// A recording read from bytes, then what `info` prints of it and its recovery line.
fn mcap(bytes: &[u8]) -> Outcome {
    match Recording::from_bytes(Path::new("<fuzz>.mcap"), bytes) {
        Ok(r) => {
            std::hint::black_box(Info::of(&r).to_string());
            std::hint::black_box(r.recovery().to_string());
            Outcome::Accepted
        }
        Err(e) => Outcome::Refused(e.to_string()),
    }
}

/// A text frame as the viewer decodes server messages (re-encoding whatever decoded, a contact
/// frame included) and as the server decodes viewer messages (`auth` before anything else,
/// `replay_control` after, each checked as the server checks it).
fn wire_messages(bytes: &[u8]) -> Outcome {
    let Ok(text) = std::str::from_utf8(bytes) else {
        return Outcome::Skipped;
    };
    let mut accepted = false;
    let mut refusal = String::new();
    match ServerMessage::decode(text) {
        Ok(message) => {
            if let ServerMessage::Contact(frame) = &message {
                std::hint::black_box(serde_json::to_string(frame).is_ok());
            }
            std::hint::black_box(message.encode().is_ok());
            accepted = true;
        }
        Err(e) => refusal = e.to_string(),
    }
    if let Ok(auth) = serde_json::from_str::<Auth>(text) {
        std::hint::black_box(format!("{auth:?}"));
        accepted = true;
    }
    if let Ok(kind) = wire::message_type(text)
        && kind == "replay_control"
    {
        match serde_json::from_str::<ReplayControl>(text) {
            Ok(control) => match control.validate() {
                Ok(()) => accepted = true,
                Err(e) => refusal = e.to_string(),
            },
            Err(e) => refusal = e.to_string(),
        }
    }
    if accepted {
        Outcome::Accepted
    } else {
        Outcome::Refused(refusal)
    }
}

// ---------------------------------------------------------------------------------------------
// Seeds.

fn read(path: &Path) -> Result<Vec<u8>, String> {
    std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))
}

/// The files directly in `dir` whose name ends in `.extension`, sorted so seed order (and thus
/// every input) does not depend on the directory's order.
fn files_with_extension(dir: &Path, extension: &str) -> Result<Vec<Vec<u8>>, String> {
    let entries = std::fs::read_dir(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let mut paths: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == extension))
        .collect();
    paths.sort();
    if paths.is_empty() {
        return Err(format!(
            "{}: no .{extension} file to seed from",
            dir.display()
        ));
    }
    paths.iter().map(|p| read(p)).collect()
}

/// Ticks of each short recording cut from a test recording, and ticks per chunk in it.
const SHORT_TICKS: usize = 300;
const SHORT_CHUNK_TICKS: usize = 100;

/// The recorded sessions cut short (their first 0.3 s, in chunks of 0.1 s: the same records,
/// channels and chunk structure, a tenth of the bytes to parse), and one whole recording. An
/// input costs about its size to read, and most mutations of a whole 4 s recording land in
/// one chunk's compressed data the reader skips, so the short ones test as much ten times as
/// fast.
fn mcap_seeds(root: &Path) -> Result<Vec<Vec<u8>>, String> {
    let dir = root.join("tests/sessions");
    let whole = dir.join("sphere-press.mcap");
    let mut seeds = vec![read(&whole)?];
    let entries = std::fs::read_dir(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let mut paths: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "mcap"))
        .collect();
    paths.sort();
    for path in paths {
        seeds.push(short_recording(&path)?);
    }
    Ok(seeds)
}

/// The first [`SHORT_TICKS`] ticks of a recording, its contact frames and marks up to then,
/// written anew by the session writer.
fn short_recording(path: &Path) -> Result<Vec<u8>, String> {
    let err = |e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
    let r = Recording::open(path).map_err(|e| err(&e))?;
    // Unique per call: the test suite builds the targets on several threads at once.
    static CALLS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let call = CALLS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let out = std::env::temp_dir().join(format!(
        "softhaptic-fuzz-seed-{}-{call}-{}",
        std::process::id(),
        path.file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned())
    ));
    let written = (|| -> Result<Vec<u8>, String> {
        let mut w = SessionWriter::create(&out, &r.build, &r.scene).map_err(|e| err(&e))?;
        let mut contacts = r.contacts.iter().peekable();
        for chunk in r
            .device
            .chunks(SHORT_CHUNK_TICKS)
            .take(SHORT_TICKS / SHORT_CHUNK_TICKS)
        {
            let end_ns = chunk.last().map_or(0, |d| d.time_ns);
            for d in chunk {
                w.write_device(d).map_err(|e| err(&e))?;
            }
            while let Some(c) = contacts.next_if(|c| c.time_ns <= end_ns) {
                w.write_contact(c.time_ns, &c.json).map_err(|e| err(&e))?;
            }
            w.end_chunk().map_err(|e| err(&e))?;
        }
        for m in &r.marks {
            let json = ServerMessage::Mark(m.clone())
                .encode()
                .map_err(|e| err(&e))?;
            w.write_mark(&json).map_err(|e| err(&e))?;
        }
        w.finish().map_err(|e| err(&e))?;
        read(&out)
    })();
    let _ = std::fs::remove_file(&out);
    written
}

fn calibration_seeds(root: &Path) -> Result<Vec<Vec<u8>>, String> {
    let dir = root.join("scenes/calibration");
    let mut seeds = files_with_extension(&dir, "json")?;
    // The limits file lives beside the tables but is another format: the limits target has it.
    let limits = read(&dir.join("model_limits.json"))?;
    seeds.retain(|s| *s != limits);
    Ok(seeds)
}

/// A grid of `n` × `n` squares (two triangles each) spaced `spacing`, as OBJ text.
pub fn obj_grid(n: usize, spacing: &str) -> String {
    let mut text = String::from("# grid\no grid\n");
    for j in 0..=n {
        for i in 0..=n {
            text.push_str(&format!("v {i}{spacing} 0 {j}{spacing}\n"));
        }
    }
    for j in 0..n {
        for i in 0..n {
            let a = j * (n + 1) + i + 1;
            let (b, c, d) = (a + 1, a + n + 1, a + n + 2);
            text.push_str(&format!("f {a} {b} {d}\nf {a} {d} {c}\n"));
        }
    }
    text
}

/// OBJ seeds: a few meshes written here (a tetrahedron, quads, grids, one with normals and
/// texture coordinates) and every `.obj` under `scenes/`.
fn obj_seeds(root: &Path) -> Result<Vec<Vec<u8>>, String> {
    let tetrahedron = "# tetrahedron\nv 0 0 0\nv 0.01 0 0\nv 0 0.01 0\nv 0 0 0.01\n\
                       f 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n";
    let quad =
        "o quad\nv -0.05 0 -0.05\nv 0.05 0 -0.05\nv 0.05 0 0.05\nv -0.05 0 0.05\nf 1 2 3 4\n";
    let with_attributes = "mtllib none.mtl\nv 0 0 0\nv 1e-2 0 0\nv 0 1e-2 0\n\
                           vt 0 0\nvt 1 0\nvt 0 1\nvn 0 0 1\nusemtl skin\ns 1\n\
                           f 1/1/1 2/2/1 3/3/1\nf -3 -2 -1\n";
    let mut seeds = vec![
        tetrahedron.as_bytes().to_vec(),
        quad.as_bytes().to_vec(),
        with_attributes.as_bytes().to_vec(),
        obj_grid(3, "e-2").into_bytes(),
        obj_grid(6, "e-3").into_bytes(),
    ];
    let mut stack = vec![root.join("scenes")];
    while let Some(dir) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        let mut paths: Vec<PathBuf> = entries.filter_map(|e| e.ok().map(|e| e.path())).collect();
        paths.sort();
        for path in paths {
            if path.is_dir() {
                stack.push(path);
            } else if path.extension().is_some_and(|x| x == "obj") {
                seeds.push(read(&path)?);
            }
        }
    }
    Ok(seeds)
}

/// The shared wire vectors (each `json` entry as text, each `raw` one as is) and the viewer's
/// own messages.
fn wire_seeds(root: &Path) -> Result<Vec<Vec<u8>>, String> {
    let path = root.join("proto/vectors/messages.json");
    let text = read(&path)?;
    let entries: Vec<serde_json::Value> =
        serde_json::from_slice(&text).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut seeds: Vec<Vec<u8>> = Vec::new();
    for entry in &entries {
        if let Some(json) = entry.get("json") {
            seeds.push(json.to_string().into_bytes());
        }
        if let Some(raw) = entry.get("raw").and_then(|r| r.as_str()) {
            seeds.push(raw.as_bytes().to_vec());
        }
    }
    for viewer in [
        r#"{"type":"auth","token":"k3Jx9-instructor"}"#,
        r#"{"type":"replay_control","action":"pause"}"#,
        r#"{"type":"replay_control","action":"seek","time_s":1.5}"#,
        r#"{"type":"replay_control","action":"play","speed":2.0}"#,
    ] {
        seeds.push(viewer.as_bytes().to_vec());
    }
    Ok(seeds)
}

// ---------------------------------------------------------------------------------------------
// The mutator.

/// xorshift64*: small, fast, and the same on every machine, which is all a fuzzer needs.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// A generator for one input; splitmix64 spreads nearby arguments over the whole state.
    pub fn for_input(seed: u64, target: &str, index: u64) -> Rng {
        let mut z = seed ^ fnv1a(target.as_bytes()) ^ index.wrapping_mul(0x9e37_79b9_7f4a_7c15);
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        // xorshift's state must not be zero.
        Rng(z | 1)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }

    /// Uniform-enough in `0..n` (`n` > 0); the modulo bias does not matter here.
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }

    fn chance(&mut self, one_in: usize) -> bool {
        self.below(one_in) == 0
    }
}

/// FNV-1a, 64 bits: a stable hash for names and crash files (std's hasher is not promised to
/// stay the same between releases).
pub fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, b| {
        (h ^ u64::from(*b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// Bytes that break parsers: ends of ranges, signs, digits, exponents, quotes and brackets.
const INTERESTING_BYTES: &[u8] = b"\x00\xff\x7f\x80-+9e.E\"[]{},:=#\n\\ ";

/// Tokens inserted or written over text: numbers at the edges of f64, f32, u32, u64, and the
/// spellings of non-numbers.
const INTERESTING_TOKENS: &[&str] = &[
    "NaN",
    "nan",
    "inf",
    "-inf",
    "Infinity",
    "1e308",
    "-1e308",
    "1e309",
    "1e39",
    "-1e39",
    "1e-320",
    "0",
    "-0",
    "-1",
    "4294967295",
    "4294967296",
    "18446744073709551615",
    "18446744073709551616",
    "-9223372036854775808",
    "99999999999999999999999999",
    "0.0000000000000000000001",
    "null",
    "true",
    "\"\"",
    "[]",
    "{}",
    "[[[[[[[[",
    "\"\\u0000\"",
    "\"\\ud800\"",
    "é",
];

/// Replacement numbers for the token-aware mutation.
const EXTREME_NUMBERS: &[&str] = &[
    "1e308",
    "-1e308",
    "1e39",
    "-1e39",
    "3.5e38",
    "1e-310",
    "0",
    "-0.0",
    "nan",
    "inf",
    "-inf",
    "4294967295",
    "4294967296",
    "18446744073709551616",
    "-1",
    "1e999",
];

/// Words in binary formats worth writing over a length or an offset.
const INTERESTING_WORDS: &[u64] = &[
    0,
    1,
    0x7f,
    0xff,
    0xffff,
    0x7fff_ffff,
    0xffff_ffff,
    0x1_0000_0000,
    0x7fff_ffff_ffff_ffff,
    u64::MAX,
];

/// Makes input number `index` for `target`: a seed (or two spliced) changed by one to eight
/// mutations.
pub fn make_input(target: &Target, seed: u64, index: u64) -> Vec<u8> {
    let mut rng = Rng::for_input(seed, target.name, index);
    let seeds = &target.seeds;
    let mut data = seeds[rng.below(seeds.len())].clone();
    let count = 1 + rng.below(8);
    for _ in 0..count {
        mutate(&mut rng, &mut data, seeds);
    }
    if target.text && std::str::from_utf8(&data).is_err() {
        data = String::from_utf8_lossy(&data).into_owned().into_bytes();
    }
    data
}

fn mutate(rng: &mut Rng, data: &mut Vec<u8>, seeds: &[Vec<u8>]) {
    if data.is_empty() {
        data.push(INTERESTING_BYTES[rng.below(INTERESTING_BYTES.len())]);
        return;
    }
    let len = data.len();
    let at = rng.below(len);
    // Runs are short mostly, occasionally long, so both fine and coarse damage happen.
    let run = if rng.chance(8) {
        1 + rng.below(len.min(4096))
    } else {
        1 + rng.below(len.min(16))
    };
    match rng.below(13) {
        0 => data[at] ^= 1 << rng.below(8),
        1 => data[at] = INTERESTING_BYTES[rng.below(INTERESTING_BYTES.len())],
        2 => data[at] = rng.next_u64() as u8,
        3 => {
            let token = INTERESTING_TOKENS[rng.below(INTERESTING_TOKENS.len())];
            data.splice(at..at, token.bytes());
        }
        4 => {
            let token = INTERESTING_TOKENS[rng.below(INTERESTING_TOKENS.len())].as_bytes();
            let end = (at + token.len()).min(len);
            data.splice(at..end, token.iter().copied());
        }
        5 => {
            data.drain(at..(at + run).min(len));
        }
        6 => {
            let bytes: Vec<u8> = (0..run).map(|_| rng.next_u64() as u8).collect();
            data.splice(at..at, bytes);
        }
        7 => {
            // Duplicate a chunk right after itself (repeated sections, tables, records).
            let chunk = data[at..(at + run).min(len)].to_vec();
            let to = (at + chunk.len()).min(data.len());
            data.splice(to..to, chunk);
        }
        8 => {
            // Splice: this input's head, another seed's tail.
            let other = &seeds[rng.below(seeds.len())];
            if !other.is_empty() {
                let from = rng.below(other.len());
                data.truncate(at);
                data.extend_from_slice(&other[from..]);
            }
        }
        9 => data.truncate(at),
        10 => replace_number(rng, data),
        11 => {
            // A little- or big-endian word over whatever is there: lengths, offsets, counts.
            let word = INTERESTING_WORDS[rng.below(INTERESTING_WORDS.len())];
            let bytes = if rng.chance(2) {
                word.to_le_bytes()
            } else {
                word.to_be_bytes()
            };
            let width = [1, 2, 4, 8][rng.below(4)];
            let bytes = if rng.chance(2) {
                &bytes[..width]
            } else {
                &bytes[8 - width..]
            };
            for (i, b) in bytes.iter().enumerate() {
                if let Some(slot) = data.get_mut(at + i) {
                    *slot = *b;
                }
            }
        }
        _ => {
            // Copy a chunk over another place of the same input.
            let chunk = data[at..(at + run).min(len)].to_vec();
            let to = rng.below(len);
            for (i, b) in chunk.iter().enumerate() {
                if let Some(slot) = data.get_mut(to + i) {
                    *slot = *b;
                }
            }
        }
    }
}

/// Token-aware: replaces one number in the text (a run of digits with its sign, point and
/// exponent) by an extreme one. Falls back to inserting one when the text has no number near.
fn replace_number(rng: &mut Rng, data: &mut Vec<u8>) {
    let is_number_byte =
        |b: u8| b.is_ascii_digit() || matches!(b, b'.' | b'-' | b'+' | b'e' | b'E');
    let replacement = EXTREME_NUMBERS[rng.below(EXTREME_NUMBERS.len())].as_bytes();
    let start = rng.below(data.len());
    // Look a bounded distance ahead for a digit so a large binary input stays cheap.
    let window = (start + 4096).min(data.len());
    let Some(digit) = data[start..window]
        .iter()
        .position(u8::is_ascii_digit)
        .map(|p| start + p)
    else {
        data.splice(start..start, replacement.iter().copied());
        return;
    };
    let mut begin = digit;
    while begin > 0 && is_number_byte(data[begin - 1]) {
        begin -= 1;
    }
    let mut end = digit;
    while end < data.len() && is_number_byte(data[end]) {
        end += 1;
    }
    data.splice(begin..end, replacement.iter().copied());
}

// ---------------------------------------------------------------------------------------------
// Running.

thread_local! {
    /// Where the last panic on this thread happened, written by [`install_quiet_panic_hook`]'s
    /// hook: `catch_unwind` hands back only the message, and a crash report needs the place.
    static LAST_PANIC: RefCell<Option<String>> = const { RefCell::new(None) };
}

/// Replaces the panic hook by one that prints nothing and remembers the message and location
/// for [`run_one`]: millions of inputs hitting the same panic would otherwise flood stderr.
pub fn install_quiet_panic_hook() {
    std::panic::set_hook(Box::new(|info| {
        let place = info
            .location()
            .map(|l| format!(" at {}:{}", l.file(), l.line()))
            .unwrap_or_default();
        let text = format!("{}{place}", panic_message(info.payload()));
        LAST_PANIC.with(|p| *p.borrow_mut() = Some(text));
    }));
}

fn panic_message(payload: &(dyn std::any::Any + Send)) -> String {
    if let Some(s) = payload.downcast_ref::<&str>() {
        (*s).to_owned()
    } else if let Some(s) = payload.downcast_ref::<String>() {
        s.clone()
    } else {
        "(a panic without a message)".to_owned()
    }
}

/// Runs one input; `Err` holds the panic's message (and place, with the quiet hook), or says
/// how far the input took the target past its memory limit.
pub fn run_one(target: &Target, input: &[u8]) -> Result<Outcome, String> {
    run_measured(target, input).0
}

/// [`run_one`], and the most memory the input made the target hold at once (0 without a
/// [`CountingAllocator`]).
pub fn run_measured(target: &Target, input: &[u8]) -> (Result<Outcome, String>, u64) {
    let run = target.run;
    LAST_PANIC.with(|p| p.borrow_mut().take());
    let from = start_measuring();
    // AssertUnwindSafe: the input is only read, and nothing the target built outlives it.
    let outcome =
        std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| run(input))).map_err(|payload| {
            LAST_PANIC
                .with(|p| p.borrow_mut().take())
                .unwrap_or_else(|| panic_message(payload.as_ref()))
        });
    let peak = measured_peak(from);
    if peak > target.max_memory_bytes {
        let refused = match &outcome {
            Ok(Outcome::Refused(e)) => format!(" before it was refused ({e})"),
            _ => String::new(),
        };
        return (
            Err(format!(
                "held {} MiB at once for an input of {} bytes{refused}; the limit is {} MiB",
                peak >> 20,
                input.len(),
                target.max_memory_bytes >> 20
            )),
            peak,
        );
    }
    (outcome, peak)
}

/// One input that panicked.
#[derive(Debug, Clone)]
pub struct Crash {
    pub index: u64,
    pub message: String,
    /// Where the input was saved (`None` if saving it failed too: the message says why).
    pub saved: Option<PathBuf>,
}

/// What a run of one target saw.
#[derive(Debug, Clone, Default)]
pub struct Stats {
    pub inputs: u64,
    pub accepted: u64,
    pub refused: u64,
    /// Inputs the target did not run (none, since text targets get valid UTF-8).
    pub skipped: u64,
    /// Distinct refusal messages once their digits are removed (line and column numbers, values
    /// echoed back), a rough count of the different ways inputs were refused.
    pub distinct_errors: HashSet<u64>,
    pub crashes: Vec<Crash>,
    /// The most memory one input made the target hold at once, bytes (0 when not counted).
    pub max_memory_bytes: u64,
}

/// Saved crash files per target at most: after that only the count grows (the same panic hit
/// a million times would otherwise fill the disk).
const MAX_SAVED_CRASHES: usize = 50;

/// Runs inputs `start..start + count` of `target`, saving any input that panicked under
/// `crash_dir`; `progress` is called every few hundred inputs with the stats so far and stops
/// the run early by returning `false` (a time budget).
pub fn run(
    target: &Target,
    seed: u64,
    start: u64,
    count: u64,
    crash_dir: &Path,
    mut progress: impl FnMut(&Stats) -> bool,
) -> Stats {
    let mut stats = Stats::default();
    for index in start..start.saturating_add(count) {
        let input = make_input(target, seed, index);
        let (outcome, peak) = run_measured(target, &input);
        stats.max_memory_bytes = stats.max_memory_bytes.max(peak);
        match outcome {
            Ok(Outcome::Accepted) => stats.accepted += 1,
            Ok(Outcome::Skipped) => stats.skipped += 1,
            Ok(Outcome::Refused(message)) => {
                stats.refused += 1;
                let kind: Vec<u8> = message.bytes().filter(|b| !b.is_ascii_digit()).collect();
                stats.distinct_errors.insert(fnv1a(&kind));
            }
            Err(message) => {
                let saved = if stats.crashes.len() < MAX_SAVED_CRASHES {
                    save_crash(crash_dir, target, &input, &message)
                } else {
                    None
                };
                stats.crashes.push(Crash {
                    index,
                    message,
                    saved,
                });
            }
        }
        stats.inputs += 1;
        if stats.inputs % 64 == 0 && !progress(&stats) {
            break;
        }
    }
    stats
}

/// Writes the input as `<target>-<hash>.<ext>` and the panic beside it (`.panic.txt`).
fn save_crash(dir: &Path, target: &Target, input: &[u8], message: &str) -> Option<PathBuf> {
    let path = dir.join(format!(
        "{}-{:016x}.{}",
        target.name,
        fnv1a(input),
        target.extension
    ));
    let written = std::fs::create_dir_all(dir)
        .and_then(|()| std::fs::write(&path, input))
        .and_then(|()| std::fs::write(path.with_extension("panic.txt"), message));
    match written {
        Ok(()) => Some(path),
        Err(e) => {
            eprintln!("could not save a crash to {}: {e}", path.display());
            None
        }
    }
}
